"""Wrap every source line longer than MAX (120) characters into lines of at most WIDTH (100), the
rest of the file as it is: ``python .ci/wrap_lines.py [PATH ...]`` (default: layercam pipelines
configs tests notebooks .ci; a notebook's ``.py`` twin wrapped, ``jupytext --sync`` it). CI holds the
limit with ruff's E501 at 120 (``.ci/run``); this is what makes a tree hold it, and it can be run
again after a merge (it leaves lines of at most 120 alone).

Compact, not a formatter's one item per line: a line is split where its outermost brackets allow,
at commas first (a call's arguments, a literal's items, a signature's parameters), else before
``and``, ``or``, ``+``, ``if``, ``else``, ``for``; the pieces are packed, aligned one column right
of the bracket they sit in (four spaces in from the line where that bracket stands far right); an
expression outside brackets gets them (``return a and b`` -> ``return (a and b)``); a long string
literal becomes adjacent literals (one string to Python; an f-string is split outside its fields);
a trailing comment that does not fit goes on its own lines above its code (below, inside brackets);
a one-line docstring becomes a paragraph. Each file's syntax tree is checked unchanged (docstrings
up to their whitespace) before it is written; the lines it cannot wrap are listed, for a hand.
"""

from __future__ import annotations

import ast
import io
import re
import sys
import textwrap
import tokenize
from pathlib import Path

MAX = 120  # lines longer than this are wrapped ...
WIDTH = 100  # ... into lines of at most this many characters
FAR = 40  # a bracket closer than this to WIDTH: its items start on the next line, four spaces in
OPEN, CLOSE = "([{", ")]}"
# split before, loosest first
TIERS = (("if", "else", "for"), ("or",), ("and",), ("+", "-"), ("*", "/", "//", "%", "@"), ("**",))
OPERAND_END = (tokenize.NAME, tokenize.NUMBER, tokenize.STRING)
SKIP = (tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.ENDMARKER)


class Tok:
    """A token of one physical line: its type and text, its columns ``[a, b)`` (relative to the
    text it is laid out in) and the bracket depth it sits at (a bracket at its outer level)."""

    __slots__ = ("type", "string", "a", "b", "depth")

    def __init__(self, type_: int, string: str, a: int, b: int, depth: int):
        self.type, self.string, self.a, self.b, self.depth = type_, string, a, b, depth

    def moved(self, d: int) -> Tok:
        return Tok(self.type, self.string, self.a + d, self.b + d, self.depth)


def _rows(src: str) -> tuple[dict[int, list[Tok]], dict[int, int], set[int]]:
    """Per physical row: its tokens, the depth it starts at; and the rows a multi-line string touches."""
    rows: dict[int, list[Tok]] = {}
    start: dict[int, int] = {}
    multi: set[int] = set()
    depth = 0
    for t in tokenize.generate_tokens(io.StringIO(src).readline):
        start.setdefault(t.start[0], depth)
        if t.type == tokenize.STRING and t.start[0] != t.end[0]:
            multi.update(range(t.start[0], t.end[0] + 1))
        if t.type == tokenize.OP and t.string in CLOSE:
            depth -= 1
        if t.type not in SKIP:
            rows.setdefault(t.start[0], []).append(Tok(t.type, t.string, t.start[1], t.end[1], depth))
        if t.type == tokenize.OP and t.string in OPEN:
            depth += 1
    return rows, start, multi


def split_string(s: str, first: int, rest: int) -> list[str] | None:
    """The string literal ``s`` as adjacent literals, the first at most ``first`` characters wide,
    the others ``rest``, each cut after a space (outside an f-string's fields); None: it cannot be."""
    m = re.match(r"([rRbBuUfF]*)(['\"])", s)
    if not m or s[len(m.group(1)) :].startswith(m.group(2) * 3) or not s.endswith(m.group(2)):
        return None
    prefix, q = m.group(1), m.group(2)
    body = s[len(prefix) + 1 : -1]
    fmt, raw = "f" in prefix.lower(), "r" in prefix.lower()
    cuts, level, i = [], 0, 0
    while i < len(body):
        c = body[i]
        if fmt and body[i : i + 2] in ("{{", "}}"):
            i += 2
            continue
        if fmt and c == "{":
            level += 1
        elif fmt and c == "}":
            level -= 1
        elif c == "\\" and not raw:
            i += 2
            continue
        elif c == " " and level == 0:
            cuts.append(i + 1)
        i += 1
    pad = len(prefix) + 2
    parts, at, room = [], 0, first
    while len(body) - at + pad > room:
        fit = [c for c in cuts if at < c and c - at + pad <= room] or [c for c in cuts if c > at][:1]
        if not fit or fit[-1] >= len(body):
            break
        parts.append(body[at : fit[-1]])
        at, room = fit[-1], rest
    parts.append(body[at:])
    if len(parts) < 2 or not all(parts):
        return None

    def literal(p: str) -> str:
        pre = prefix if not fmt or re.search(r"[{}]", p) else re.sub("[fF]", "", prefix)
        return f"{pre}{q}{p}{q}"

    return [literal(p) for p in parts]


def _cuts(toks: list[Tok]) -> list[tuple[int, str]]:
    """Where the tokens may be split: ``(offset, joiner)`` pairs at the shallowest bracket depth
    (1 or more) that has any: after its commas, else before its operators, the loosest binding
    first (``TIERS``); [] for none."""
    last = len(toks) - 1

    def tier(i: int, t: Tok) -> int | None:
        if t.depth < 1 or t.type not in (tokenize.OP, tokenize.NAME):
            return None
        if t.string == ",":
            return 0 if i < last else None
        prev = toks[i - 1] if i > 0 else None
        if prev is None or not (prev.type in OPERAND_END or prev.string in CLOSE):
            return None  # a unary sign, *args, the start
        return next((k + 1 for k, ops in enumerate(TIERS) if t.string in ops), None)

    found = [(i, t, k) for i, t in enumerate(toks) if (k := tier(i, t)) is not None]
    if not found:
        return []
    lv = min(t.depth for _, t, _ in found)
    best = min(k for _, t, k in found if t.depth == lv)
    return [(t.b, " ") if k == 0 else (t.a, " ") for _, t, k in found if t.depth == lv and k == best]


def _owner_col(toks: list[Tok], offset: int) -> int | None:
    """The column (relative) right after the innermost bracket opened in ``toks`` before ``offset``
    and still open there; None when the split sits in a bracket opened before these tokens."""
    stack = []
    for t in toks:
        if t.a >= offset:
            break
        if t.type == tokenize.OP and t.string in OPEN:
            stack.append(t.b)
        elif t.type == tokenize.OP and t.string in CLOSE and stack:
            stack.pop()
    return stack[-1] if stack else None


def layout(text: str, toks: list[Tok], col: int, cont: int, indent: int) -> list[str] | None:
    """``text`` (spanned by ``toks``, columns relative to it) laid out from column ``col``; pieces
    in a bracket opened before the text continue at ``cont``; ``indent``: the statement's. Returns
    the lines (the first without its column, the others with theirs), or None."""
    if col + len(text) <= WIDTH or not toks:
        return [text]
    cuts = _cuts(toks)
    if cuts:
        owner = _owner_col(toks, cuts[0][0])
        at = cont if owner is None else col + owner
        if owner is not None and at > WIDTH - FAR:  # the bracket stands far right: its items on the next lines
            at = indent + 4 if indent + 4 < cont or owner is not None else cont
            cuts = [(owner, "")] + cuts
        return _pack(text, toks, cuts, col, at, indent)
    strings = [t for t in toks if t.type == tokenize.STRING and t.depth >= 1]
    if strings:
        s = max(strings, key=lambda t: len(t.string))
        parts = split_string(s.string, WIDTH - col - s.a, WIDTH - col - s.a)
        if parts:
            lines = [text[: s.a] + parts[0]] + [" " * (col + s.a) + p for p in parts[1:]]
            lines[-1] += text[s.b :]
            return lines
    return None


def _pack(text: str, toks: list[Tok], cuts: list[tuple[int, str]], col: int, cont: int,
          indent: int) -> list[str] | None:
    bounds = [0] + [c for c, _ in cuts] + [len(text)]
    joins = [""] + [j for _, j in cuts]
    lines: list[str] = []
    cur = ""  # the line being filled, with its indentation (the first: without)
    for k in range(len(bounds) - 1):
        a, b = bounds[k], bounds[k + 1]
        raw = text[a:b]
        lead = len(raw) - len(raw.lstrip())
        piece = raw.strip()
        ptoks = [t.moved(-(a + lead)) for t in toks if a <= t.a < b]
        start = col if k == 0 else None
        if k > 0:
            width_now = (col if not lines else 0) + len(cur)
            if width_now + len(joins[k]) + len(piece) <= WIDTH:
                cur += joins[k] + piece
                continue
            lines.append(cur)
            cur, start = " " * cont, cont
        first_col = (col + len(cur)) if k == 0 else start
        if first_col + len(piece) <= WIDTH:
            cur += piece
            continue
        sub = layout(piece, ptoks, first_col, first_col, indent)
        if sub is None:
            return None
        cur += sub[0]
        for s in sub[1:]:
            lines.append(cur)
            cur = s
    lines.append(cur)
    return lines


def _comment(text: str, indent: int) -> list[str]:
    body = text.strip().removeprefix("#").strip()
    return [" " * indent + "# " + s
            for s in textwrap.wrap(body, WIDTH - indent - 2, break_long_words=False,
                                   break_on_hyphens=False)]


def _bracketed(body: str, toks: list[Tok]) -> tuple[str, list[Tok]] | None:
    """A statement whose long part is outside any bracket, its expression put in one:
    ``x = a and b``, ``return "..."``, ``if a or b:`` (None: no such expression)."""
    heads = ("return", "yield", "if", "elif", "while", "assert", "raise", "del", "in")
    if toks[0].string == "from":  # from a import b, c -> from a import (b, c)
        start = next((i + 1 for i, t in enumerate(toks) if t.string == "import"), None)
    else:
        start = next((i + 1 for i, t in enumerate(toks)
                      if t.depth == 0
                      and (t.string in ("=", "+=", "-=", "|=", ":=")
                           or i == 0 and t.string in heads)), None)
    if start is None or start >= len(toks) or toks[start].string in OPEN and toks[-1].string in CLOSE:
        return None
    end = len(toks) - (1 if toks[-1].string == ":" else 0)
    end = next((k for k in range(start, end)
                if toks[k].depth == 0 and toks[k].string == "from" and toks[0].string == "raise"),
               end)
    if toks[0].string == "assert":  # its condition or its message, never both (a tuple is always true)
        comma = next((k for k in range(start, end) if toks[k].depth == 0 and toks[k].string == ","), None)
        if comma is not None:
            cond, msg = toks[comma - 1].b - toks[start].a, toks[end - 1].b - toks[comma + 1].a
            start, end = (start, comma) if cond >= msg else (comma + 1, end)
    a, b = toks[start].a, toks[end - 1].b
    out = [t if k < start else t.moved(1 if k < end else 2) for k, t in enumerate(toks)]
    for t in out[start:end]:
        t.depth += 1
    out = out[:start] + [Tok(tokenize.OP, "(", a, a + 1, 0)] + out[start:end] + [Tok(tokenize.OP,
                             ")", b + 1, b + 2, 0)] + out[end:]
    return body[:a] + "(" + body[a:b] + ")" + body[b:], out


def wrap_line(line: str, toks: list[Tok], depth0: int) -> list[str] | None:
    """One long physical line (its tokens, the bracket depth it starts at) as lines of at most WIDTH."""
    indent = len(line) - len(line.lstrip())
    comment = toks[-1] if toks and toks[-1].type == tokenize.COMMENT else None
    code = toks[:-1] if comment else toks
    if not code:
        return _comment(line, indent)
    body = line[indent : code[-1].b]
    rel = [t.moved(-indent) for t in code]
    lines = [line[: code[-1].b]]
    if len(lines[0]) > WIDTH:
        block = depth0 == 0 and rel[-1].string == ":" and rel[0].string in ("if", "elif", "while",
            "for", "with", "def", "class", "async")
        cont = indent + (8 if block else 4) if depth0 == 0 else indent
        sub = layout(body, rel, indent, cont, indent)
        if sub is None and depth0 == 0 and (made := _bracketed(body, rel)) is not None:
            sub = layout(*made, indent, cont, indent)
        if sub is None:
            return None
        lines = [" " * indent + sub[0]] + sub[1:]
    if comment is None:
        return lines
    c = line[comment.a :]
    opener = rel[-1].string == ":"
    if len(lines) == 1 and comment.a <= WIDTH - 30:  # kept where it stands, its rest aligned under it
        text = _comment(c, comment.a)
        return [lines[0] + " " * (comment.a - len(lines[0])) + text[0].lstrip()] + text[1:]
    if len(lines[-1]) + 2 + len(c) <= WIDTH:
        lines[-1] += "  " + c
        return lines
    if opener:  # a block's header: the comment opens its body
        return lines + _comment(c, indent + 4)
    return lines + _comment(c, indent) if depth0 > 0 else _comment(c, indent) + lines


def docstring(line: str) -> list[str] | None:
    """A one-line docstring (``\"\"\"...\"\"\"`` alone on its line) as a paragraph."""
    m = re.fullmatch(r'(\s*)([rR]?"""|[rR]?\'\'\')(.*)("""|\'\'\')', line)
    if not m or ">>>" in m.group(3) or m.group(3).endswith(('"', "\\")):
        return None
    ind, q = m.group(1), m.group(2)
    words = textwrap.wrap(q + m.group(3) + m.group(4), WIDTH - len(ind), break_long_words=False, break_on_hyphens=False)
    return [ind + w for w in words] if len(words) > 1 else None


def _docstring_rows(src: str) -> set[int]:
    """The rows of every docstring's text, but its doctests (``>>>`` to the next blank line)."""
    rows: set[int] = set()
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Module)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value,
                          ast.Constant) and isinstance(first.value.value, str):
                rows.update(range(first.lineno, first.end_lineno + 1))
    lines, doctest = src.split("\n"), False
    for r, line in enumerate(lines, 1):
        doctest = line.strip().startswith(">>>") or doctest and bool(line.strip())
        if doctest:
            rows.discard(r)
    return rows


def split_text(line: str, indent: str) -> list[str] | None:
    """A long line of a docstring's text cut at its last space within WIDTH, the rest on the next
    line at ``indent`` (and so on)."""
    out = []
    while len(line) > WIDTH:
        cut = line.rfind(" ", len(indent) + 1, WIDTH + 1)
        if cut <= len(line) - len(line.lstrip()):
            return None
        out.append(line[:cut].rstrip())
        line = indent + line[cut + 1 :].lstrip()
    return out + [line]


def _normalised(tree: ast.AST) -> str:
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Module)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value,
                          ast.Constant) and isinstance(first.value.value, str):
                first.value.value = " ".join(first.value.value.split())
    return ast.dump(tree)


def wrap_file(path: Path) -> list[str]:
    """Wraps ``path`` in place; returns what it could not wrap (``path:row``)."""
    src = path.read_text()
    lines = src.split("\n")
    left: list[str] = []
    for _ in range(4):  # a piece a pass wrapped may need another
        text = "\n".join(lines)
        rows, starts, multi = _rows(text)
        docs = _docstring_rows(text)
        out, left = [], []
        for r, line in enumerate(lines, 1):
            new = None
            # a backslash: by hand
            joined = line.rstrip().endswith("\\") or r > 1 and lines[r - 2].rstrip().endswith("\\")
            if len(line) > MAX and r in docs and r in multi:
                nxt = lines[r] if r < len(lines) else ""
                new = split_text(line,
                                 " "
                                 * (len(nxt) - len(nxt.lstrip()) if nxt.strip()
                                    else len(line) - len(line.lstrip())))
            elif len(line) > MAX and r not in multi and not joined:
                new = docstring(line) or wrap_line(line, rows.get(r, []), starts.get(r, 0))
            if len(line) > MAX and (new is None or any(len(s) > MAX for s in new)):
                left.append(f"{path}:{len(out) + 1}")
                new = None
            out.extend(new or [line])
        if out == lines:
            break
        lines = out
    new_src = "\n".join(lines)
    if new_src != src:
        try:
            same = _normalised(ast.parse(src)) == _normalised(ast.parse(new_src))
        except SyntaxError as e:
            return [f"{path}: the wrapped file does not parse ({e}); left as it was"]
        if not same:
            return [f"{path}: wrapping changed the syntax tree; left as it was"]
        path.write_text(new_src)
    return left


def main(argv: list[str]) -> int:
    roots = [Path(a) for a in (argv or ["layercam", "pipelines", "configs", "tests", "notebooks", ".ci"])]
    files = [p for r in roots for p in (sorted(r.rglob("*.py")) if r.is_dir() else [r])]
    left = [x for p in files for x in wrap_file(p)]
    for x in left:
        print(f"not wrapped: {x}", file=sys.stderr)
    return 1 if left else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
