"""Self-contained HTML (figures embedded as data URIs) and Markdown from one list of sections.

A section is ``(title, blocks)``; a block is ``("p", text)``, ``("table", header, rows)`` or
``("figure", png_bytes, caption)``. The HTML carries a small script that counts the images that
decoded and writes the count on ``<body data-images-ok=...>`` (the browser test reads it).
"""
from __future__ import annotations

import base64
import html


def _fmt(v) -> str:
    if isinstance(v, float):
        if v != v:
            return "-"
        a = abs(v)
        return f"{v:.3e}" if (a and (a < 1e-3 or a >= 1e6)) else f"{v:.4f}"
    return str(v)


CSS = """body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:1em 0;font-size:13px}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}
th{background:#f2f2f2}td:first-child,th:first-child{text-align:left}figure{margin:1em 0}img{max-width:100%}
.flag{color:#b00;font-weight:bold}figcaption{font-size:13px;color:#555}"""

SCRIPT = """window.addEventListener('load',function(){var imgs=document.images,ok=0,bad=[];
for(var i=0;i<imgs.length;i++){if(imgs[i].complete&&imgs[i].naturalWidth>0){ok++;}else{bad.push(imgs[i].alt);}}
document.body.setAttribute('data-images-ok',ok);document.body.setAttribute('data-images-total',imgs.length);
if(bad.length){console.error('broken images: '+bad.join(', '));}});"""


def to_html(title: str, sections) -> str:
    out = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
           f"<style>{CSS}</style><script>{SCRIPT}</script></head><body><h1>{html.escape(title)}</h1>"]
    for sec_title, blocks in sections:
        out.append(f"<h2>{html.escape(sec_title)}</h2>")
        for b in blocks:
            if b[0] == "p":
                out.append(f"<p>{html.escape(b[1])}</p>")
            elif b[0] == "table":
                out.append("<table><tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in b[1]) + "</tr>")
                for row in b[2]:
                    cells = []
                    for v in row:
                        s = html.escape(_fmt(v))
                        cells.append(f"<td class='flag'>{s}</td>" if isinstance(v, str) and v.startswith("!") else f"<td>{s}</td>")
                    out.append("<tr>" + "".join(cells) + "</tr>")
                out.append("</table>")
            elif b[0] == "figure":
                data = base64.b64encode(b[1]).decode()
                out.append(f"<figure><img alt='{html.escape(b[2])}' src='data:image/png;base64,{data}'>"
                           f"<figcaption>{html.escape(b[2])}</figcaption></figure>")
    out.append("</body></html>")
    return "\n".join(out)


def to_markdown(title: str, sections) -> str:
    out = [f"# {title}", ""]
    for sec_title, blocks in sections:
        out += [f"## {sec_title}", ""]
        for b in blocks:
            if b[0] == "p":
                out += [b[1], ""]
            elif b[0] == "table":
                out.append("| " + " | ".join(str(h) for h in b[1]) + " |")
                out.append("|" + "---|" * len(b[1]))
                for row in b[2]:
                    out.append("| " + " | ".join(_fmt(v) for v in row) + " |")
                out.append("")
            elif b[0] == "figure":
                out += [f"*Figure: {b[2]} (in the HTML report)*", ""]
    return "\n".join(out)
