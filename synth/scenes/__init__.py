"""What a render shows: scenes, objects, meshes, printed boards, poses, pattern sequences, and the paper's calibration session."""
