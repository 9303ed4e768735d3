r"""The evaluation's Markdown report as one self-contained HTML page.

    python -m vlc_evaluation.html_report docs/RESULTS.md [-o docs/RESULTS.html]

Reads the Markdown the evaluation writes (``docs/RESULTS.md``, :mod:`.report`) and writes
an HTML page that needs no other file: the PNG figures it links are embedded as base64
``data:`` URIs, the style sheet is inline. :func:`vlc_evaluation.report.update_markdown`
writes ``docs/RESULTS.html`` beside ``docs/RESULTS.md`` every time.

The Markdown understood is what the report uses: ATX headings (``#`` … ``######``), pipe
tables (a header row, a ``|---|`` row with optional ``:`` alignment, body rows; ``\|`` in a
cell), paragraphs, ``-``/``*``/``1.`` lists, fenced code blocks, HTML comments (left out),
and inline code spans, ``**bold**``, ``*emphasis*``, ``[links](url)`` and
``![images](file.png)``. Anything else is kept as escaped text. An image file that is
missing (or not a PNG, JPEG, GIF or SVG) keeps its link and is listed in the result.
"""
import argparse
import base64
from dataclasses import dataclass, field
import html
import pathlib
import re
import sys

MIME = {'.png': 'image/png', '.jpg': 'image/jpeg', '.jpeg': 'image/jpeg',
        '.gif': 'image/gif', '.svg': 'image/svg+xml'}
STYLE = """
body { font-family: system-ui, -apple-system, 'Segoe UI', sans-serif; max-width: 1200px;
       margin: 2em auto; padding: 0 1em; color: #1d1d1f; line-height: 1.45; }
h1, h2, h3, h4 { line-height: 1.2; margin-top: 1.6em; }
h1 { border-bottom: 2px solid #d0d0d7; padding-bottom: .3em; }
h2 { border-bottom: 1px solid #e0e0e6; padding-bottom: .2em; }
table { border-collapse: collapse; margin: 1em 0; font-size: .9em; display: block;
        overflow-x: auto; }
th, td { border: 1px solid #d0d0d7; padding: .3em .6em; text-align: left; }
th { background: #f2f2f6; }
tr:nth-child(even) td { background: #fafafc; }
code { font-family: ui-monospace, 'SFMono-Regular', Menlo, monospace; font-size: .88em;
       background: #f2f2f6; padding: .1em .3em; border-radius: 3px; }
pre { background: #f2f2f6; padding: .8em; overflow-x: auto; }
pre code { background: none; padding: 0; }
figure { margin: 1em 0; }
figure img { max-width: 100%; border: 1px solid #e0e0e6; }
figcaption { font-size: .85em; color: #555; }
""".strip()

_HEADING = re.compile(r'^(#{1,6})\s+(.*?)\s*#*\s*$')
_TABLE_RULE = re.compile(r'^\s*\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?\s*$')
_LIST_ITEM = re.compile(r'^(\s*)([-*]|\d+[.)])\s+(.*)$')
_FENCE = re.compile(r'^\s*(```|~~~)')
_IMAGE_ONLY = re.compile(r'^\s*!\[([^\]]*)\]\(([^)\s]+)(?:\s+"[^"]*")?\)\s*$')
_INLINE = re.compile(
    r'(?P<code>`+)(?P<code_text>.+?)(?P=code)'
    r'|!\[(?P<img_alt>[^\]]*)\]\((?P<img_src>[^)\s]+)(?:\s+"[^"]*")?\)'
    r'|\[(?P<link_text>[^\]]+)\]\((?P<link_href>[^)\s]+)(?:\s+"[^"]*")?\)'
    r'|\*\*(?P<bold>.+?)\*\*'
    r'|(?<![\w*])\*(?P<em>[^*\s][^*]*?)\*(?![\w*])')


@dataclass
class HtmlReport:
    """A converted page: ``html`` text, ``embedded`` image files (paths as linked) and
    ``missing`` images (linked but not embedded).
    """

    html: str
    embedded: list = field(default_factory=list)
    missing: list = field(default_factory=list)


class _Converter:
    def __init__(self, base_dir):
        self.base_dir = pathlib.Path(base_dir)
        self.embedded, self.missing = [], []

    # ------------------------------------------------------------------ inline
    def image_src(self, src):
        """``src`` as a data URI when it is a local image file, else as given."""
        if re.match(r'^[a-z][a-z0-9+.-]*:', src, re.IGNORECASE):
            return src                              # http:, data:, …
        path = self.base_dir / src
        mime = MIME.get(path.suffix.lower())
        if mime is None or not path.is_file():
            self.missing.append(src)
            return src
        self.embedded.append(src)
        data = base64.b64encode(path.read_bytes()).decode('ascii')
        return f'data:{mime};base64,{data}'

    def inline(self, text):
        out, pos = [], 0
        for m in _INLINE.finditer(text):
            out.append(html.escape(text[pos:m.start()], quote=False))
            pos = m.end()
            if m.group('code'):
                out.append(f'<code>{html.escape(m.group("code_text").strip())}</code>')
            elif m.group('img_src') is not None:
                out.append(f'<img src="{html.escape(self.image_src(m.group("img_src")))}" '
                           f'alt="{html.escape(m.group("img_alt"))}">')
            elif m.group('link_href') is not None:
                out.append(f'<a href="{html.escape(m.group("link_href"))}">'
                           f'{self.inline(m.group("link_text"))}</a>')
            elif m.group('bold') is not None:
                out.append(f'<strong>{self.inline(m.group("bold"))}</strong>')
            else:
                out.append(f'<em>{self.inline(m.group("em"))}</em>')
        out.append(html.escape(text[pos:], quote=False))
        return ''.join(out)

    # ------------------------------------------------------------------ blocks
    @staticmethod
    def cells(row):
        row = row.strip()
        if row.startswith('|'):
            row = row[1:]
        if row.endswith('|') and not row.endswith('\\|'):
            row = row[:-1]
        return [c.strip().replace('\\|', '|') for c in re.split(r'(?<!\\)\|', row)]

    def table(self, lines):
        header, rule, body = self.cells(lines[0]), self.cells(lines[1]), lines[2:]
        aligns = []
        for cell in rule:
            left, right = cell.startswith(':'), cell.endswith(':')
            aligns.append('center' if left and right else 'right' if right else
                          'left' if left else '')

        def row(cells, tag):
            out = []
            for i, cell in enumerate(cells):
                align = aligns[i] if i < len(aligns) else ''
                style = f' style="text-align: {align}"' if align else ''
                out.append(f'<{tag}{style}>{self.inline(cell)}</{tag}>')
            return '<tr>' + ''.join(out) + '</tr>'
        head = row(header, 'th')
        rows = '\n'.join(row(self.cells(line), 'td') for line in body)
        return f'<table>\n<thead>{head}</thead>\n<tbody>\n{rows}\n</tbody>\n</table>'

    def items(self, lines):
        ordered = bool(re.match(r'^\s*\d', lines[0]))
        items = []
        for line in lines:
            m = _LIST_ITEM.match(line)
            if m:
                items.append(m.group(3))
            elif items:
                items[-1] += ' ' + line.strip()     # a continuation line
        tag = 'ol' if ordered else 'ul'
        body = '\n'.join(f'<li>{self.inline(item)}</li>' for item in items)
        return f'<{tag}>\n{body}\n</{tag}>'

    def convert(self, text):
        text = re.sub(r'<!--.*?-->', '', text, flags=re.DOTALL)
        lines = text.splitlines()
        blocks, title = [], None
        i = 0
        while i < len(lines):
            line = lines[i]
            if not line.strip():
                i += 1
                continue
            if _FENCE.match(line):
                fence = _FENCE.match(line).group(1)
                j = i + 1
                while j < len(lines) and not lines[j].strip().startswith(fence):
                    j += 1
                code = html.escape('\n'.join(lines[i + 1:j]))
                blocks.append(f'<pre><code>{code}</code></pre>')
                i = j + 1
                continue
            m = _HEADING.match(line)
            if m:
                level = len(m.group(1))
                content = self.inline(m.group(2))
                if title is None and level == 1:
                    title = re.sub(r'<[^>]+>', '', content)
                anchor = re.sub(r'[^a-z0-9]+', '-', html.unescape(
                    re.sub(r'<[^>]+>', '', content)).lower()).strip('-')
                blocks.append(f'<h{level} id="{anchor}">{content}</h{level}>')
                i += 1
                continue
            if '|' in line and i + 1 < len(lines) and _TABLE_RULE.match(lines[i + 1]):
                j = i + 2
                while j < len(lines) and lines[j].strip() and '|' in lines[j]:
                    j += 1
                blocks.append(self.table(lines[i:j]))
                i = j
                continue
            if _LIST_ITEM.match(line):
                j = i + 1
                while j < len(lines) and lines[j].strip() and (
                        _LIST_ITEM.match(lines[j]) or lines[j].startswith((' ', '\t'))):
                    j += 1
                blocks.append(self.items(lines[i:j]))
                i = j
                continue
            m = _IMAGE_ONLY.match(line)
            if m:
                alt, src = m.group(1), m.group(2)
                blocks.append(f'<figure><img src="{html.escape(self.image_src(src))}" '
                              f'alt="{html.escape(alt)}"><figcaption>{html.escape(alt)}'
                              '</figcaption></figure>')
                i += 1
                continue
            j = i
            paragraph = []
            while j < len(lines) and lines[j].strip() and not (
                    _HEADING.match(lines[j]) or _FENCE.match(lines[j])
                    or _LIST_ITEM.match(lines[j]) or _IMAGE_ONLY.match(lines[j])
                    or (j + 1 < len(lines) and '|' in lines[j]
                        and _TABLE_RULE.match(lines[j + 1]))):
                paragraph.append(lines[j].strip())
                j += 1
            blocks.append(f'<p>{self.inline(" ".join(paragraph))}</p>')
            i = j
        return blocks, title


def markdown_to_html(text, base_dir='.', title=None):
    """Markdown text → :class:`HtmlReport`; images are looked up relative to ``base_dir``
    (the Markdown file's folder); ``title`` defaults to the first ``#`` heading.
    """
    converter = _Converter(base_dir)
    blocks, heading = converter.convert(text)
    page_title = html.escape(title or heading or 'Report')
    body = '\n'.join(blocks)
    page = ('<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f'<title>{page_title}</title>\n<style>\n{STYLE}\n</style>\n</head>\n<body>\n'
            f'{body}\n</body>\n</html>\n')
    return HtmlReport(page, converter.embedded, converter.missing)


def write_html(markdown_path, html_path=None):
    """Convert the Markdown file ``markdown_path`` into ``html_path`` (default: the same
    name with ``.html``); returns the :class:`HtmlReport` with its ``path``.
    """
    markdown_path = pathlib.Path(markdown_path)
    html_path = pathlib.Path(html_path) if html_path else markdown_path.with_suffix('.html')
    report = markdown_to_html(markdown_path.read_text(encoding='utf-8'),
                              markdown_path.parent)
    html_path.write_text(report.html, encoding='utf-8')
    report.path = html_path
    return report


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('markdown', help='the Markdown report (e.g. docs/RESULTS.md)')
    parser.add_argument('-o', '--output', help='HTML file (default: beside it, .html)')
    args = parser.parse_args(argv)
    try:
        report = write_html(args.markdown, args.output)
    except OSError as exc:
        print(f'html_report: error: {exc}', file=sys.stderr)
        return 2
    print(f'{report.path}: {len(report.embedded)} image(s) embedded, '
          f'{len(report.html) / 1e6:.1f} MB')
    for src in report.missing:
        print(f'html_report: warning: image {src} not found; kept as a link', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
