#!/usr/bin/env python3
"""No function in include/, src/, apps/, tools/ or python/src/ longer than LIMIT lines without a reason in its file (docs/architecture.md,
"Functions with one job").

    scripts/check-function-length.py [SOURCE_DIR] [--limit N] [--list M]

exit 0: clean, 1: a function over the limit without a reason. A reason is a comment in the same file
of the form `// long function <name>: <why>`. --list M prints every function longer than M lines.

The scan is lexical, not a C++ parser: comments, string and character literals are blanked, then
each `{` at namespace or class scope whose head (the text since the previous `;`, `{` or `}`)
holds a `)` and is not an initialiser (`= {`) opens a function body, measured to its matching `}`.
"""
import pathlib
import re
import sys

LIMIT = 120
# The library (public headers and sources), the CLI, the tools and the Python module.
DIRS = ("include", "src", "apps", "tools", "python/src")


def blank_literals(text: str) -> str:
    """Comments, strings and chars replaced by spaces (newlines kept, so line numbers hold)."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == "R" and text.startswith('R"', i) and (i == 0 or not text[i - 1].isalnum()):
            m = re.match(r'R"([^(\s]*)\(', text[i:])
            if not m:
                out.append(c)
                i += 1
                continue
            end = ")" + m.group(1) + '"'
            j = text.find(end, i + m.end())
            j = n if j < 0 else j + len(end)
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c in "\"'":
            # A digit separator (1'000) is not a character literal.
            if c == "'" and i > 0 and text[i - 1].isalnum() and i + 1 < n and text[i + 1].isalnum():
                out.append(" ")
                i += 1
                continue
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            j = min(j + 1, n)
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        else:
            out.append(c)
            i += 1
    # preprocessor lines (and their continuations) blanked too
    return re.sub(r"(?m)^[ \t]*#(?:.*\\\n)*.*$", lambda m: re.sub(r"[^\n]", " ", m.group(0)),
                  "".join(out))


def matching_brace(code: str, i: int) -> int:
    depth = 0
    for j in range(i, len(code)):
        if code[j] == "{":
            depth += 1
        elif code[j] == "}":
            depth -= 1
            if depth == 0:
                return j
    return len(code) - 1


def function_name(head: str) -> str:
    h = re.sub(r"\s+", " ", head)
    # the identifier before the parameter list's '(' (the first '(' not in a template argument)
    m = re.search(r"([~\w:]+(?:operator\s*\S+?)?)\s*\(", h)
    return m.group(1) if m else h.strip()[:60]


def functions(code: str):
    """(name, first line, lines) of every function body at namespace or class scope."""
    scopes = []  # 'ns' or 'class' for each open scope we descend into
    i, n, last = 0, len(code), 0
    while i < n:
        c = code[i]
        if c in ";":
            last = i + 1
        elif c == "}":
            if scopes:
                scopes.pop()
            last = i + 1
        elif c == "{":
            head = code[last:i]
            hs = head.strip()
            hs_no_template = re.sub(r"^template\s*<[^{;]*?>\s*", "", hs)
            if re.match(r"(namespace\b|extern\s*$)", hs) or hs == "":
                scopes.append("ns")
            elif re.search(r"\b(class|struct|union|enum)\b", hs_no_template.split("(")[0]) and not re.search(
                r"\)\s*(const\s*)?(noexcept\s*)?(override\s*)?(->.*)?$", hs
            ):
                scopes.append("class")
            elif ")" in hs and not re.search(r"=\s*$", hs):
                j = matching_brace(code, i)
                first = code.count("\n", 0, i) + 1
                lines = code.count("\n", i, j) + 1
                # the head's own lines (a long parameter list) count too
                head_lines = hs.count("\n")
                yield function_name(hs), first - head_lines, lines + head_lines
                i, last = j + 1, j + 1
                continue
            else:  # an initialiser, a requires-clause or anything else: skipped whole
                j = matching_brace(code, i)
                i, last = j + 1, j + 1
                continue
            last = i + 1
        i += 1


def main(argv):
    root = pathlib.Path(".")
    limit, list_over = LIMIT, None
    args = list(argv)
    while args:
        a = args.pop(0)
        if a == "--limit":
            limit = int(args.pop(0))
        elif a == "--list":
            list_over = int(args.pop(0))
        else:
            root = pathlib.Path(a)
    status = 0
    files = sorted(f for d in DIRS for f in (root / d).rglob("*.[ch]pp"))
    if not files:
        print(f"check-function-length: no sources under {root} ({', '.join(DIRS)})", file=sys.stderr)
        return 2
    for f in files:
        text = f.read_text(encoding="utf-8")
        reasons = set(re.findall(r"//\s*long function ([~\w:]+):\s*\S", text))
        for name, line, lines in functions(blank_literals(text)):
            rel = f.relative_to(root)
            if list_over is not None and lines > list_over:
                print(f"{lines:5d}  {rel}:{line}  {name}")
            short = name.split("::")[-1]
            if lines > limit and name not in reasons and short not in reasons:
                print(
                    f"{rel}:{line}: function '{name}' is {lines} lines (limit {limit}); split it "
                    f"or give the reason in the file: // long function {short}: <why>",
                    file=sys.stderr,
                )
                status = 1
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
