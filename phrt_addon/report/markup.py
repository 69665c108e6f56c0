"""Report items as Markdown and HTML.
"""
import html
import re
from dataclasses import dataclass


@dataclass
class ReportTable:
    """A table of the report: title, header, rows of cells (text) and an introduction."""

    title: str
    header: list
    rows: list
    intro: str = ""


def _markdown_cell(text):
    return str(text).replace("|", "\\|").replace("\n", " ")


def to_markdown(items):
    lines = []
    for item in items:
        kind = item[0]
        if kind == "h1":
            lines += [f"# {item[1]}", ""]
        elif kind == "p":
            lines += [item[1], ""]
        elif kind == "img":
            lines += [f"![{item[2]}]({item[1]})", "", f"*{item[2]}*", ""]
        else:
            table = item[1]
            lines += [f"## {table.title}", ""]
            if table.intro:
                lines += [table.intro, ""]
            lines.append("| " + " | ".join(_markdown_cell(h) for h in table.header) + " |")
            lines.append("|" + "|".join("---" for _ in table.header) + "|")
            lines += ["| " + " | ".join(_markdown_cell(c) for c in row) + " |" for row in table.rows]
            lines.append("")
    return "\n".join(lines)


_CSS = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse;margin:0.5em 0 1.5em}"
        "th,td{border:1px solid #bbb;padding:3px 8px;text-align:right}"
        "th{background:#eee}td:first-child,th:first-child{text-align:left}"
        "img{max-width:100%}figcaption{font-style:italic;margin-bottom:1.5em}")


def to_html(items):
    escape = html.escape
    body = []
    for item in items:
        kind = item[0]
        if kind == "h1":
            body.append(f"<h1>{escape(item[1])}</h1>")
        elif kind == "p":
            body.append(f"<p>{escape(item[1])}</p>")
        elif kind == "img":
            body.append(f'<figure><img src="{escape(item[1])}" alt="{escape(item[2])}">'
                        f"<figcaption>{escape(item[2])}</figcaption></figure>")
        else:
            table = item[1]
            body.append(f"<h2>{escape(table.title)}</h2>")
            if table.intro:
                body.append(f"<p>{_html_links(escape(table.intro))}</p>")
            head = "".join(f"<th>{escape(h)}</th>" for h in table.header)
            rows = "".join("<tr>" + "".join(f"<td>{escape(str(c))}</td>" for c in row) + "</tr>"
                           for row in table.rows)
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>")
    return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>PHRT report</title>"
            f"<style>{_CSS}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def _html_links(text):
    """Turn the markdown link ``[name](name)`` of an escaped paragraph into <a>."""
    return re.sub(r"\[([^\]]+)\]\(([^)]+)\)", r'<a href="\2">\1</a>', text)
