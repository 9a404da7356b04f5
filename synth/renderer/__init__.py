"""The renderer: geometry (rays, hits, shading), the pattern stage, the render loop, ground truth and the files a render writes."""
