#!/usr/bin/env python3
"""Check the relative links in the repository's Markdown files.

For every *.md file (outside target/, hidden directories and the fuzz/ corpus, artifact and build directories),
every inline link or image `[text](path)` / `[text](path#anchor)` and every reference definition `[id]: path`
must name an existing file or directory, relative to the linking file (or to the repository root when it starts
with '/'). An #anchor into a .md file (or a bare #anchor, into the file itself) must match a heading's
GitHub-style slug: lowercase, spaces to '-', punctuation dropped except '-' and '_', a repeated heading getting
-1, -2, ... Links with a scheme (http:, https:, mailto:, ...) are not checked. Code blocks are skipped.

A code span that names a path in the repository (`lbv-master-fw/src/update/own.rs`, `docs/`: segments joined by '/',
the first one a top-level file or directory of the repository) must name one that exists, so that prose cannot
keep pointing at a file that moved or went. Spans with a space, a glob or a placeholder (`*`, `<`, `{`) are not
paths and are not checked, nor are build outputs (under `target/`).

Usage: docs/check-links.py [ROOT]   (ROOT defaults to the repository this script is in)
Prints each broken link as `file:line: broken link TARGET` and exits 1 if there is any, else prints a summary
and exits 0.
"""

import os
import re
import sys
from urllib.parse import unquote

SKIP_DIRS = {"target", "node_modules", "__pycache__"}
SKIP_UNDER_FUZZ = {"corpus", "artifacts", "coverage", "target"}

INLINE = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*(<[^>]*>|[^\s)]+(?:\([^\s)]*\)[^\s)]*)*)(?:\s+(?:\"[^\"]*\"|'[^']*'|\([^)]*\)))?\s*\)")
REFERENCE = re.compile(r"^ {0,3}\[[^\]]+\]:\s*(<[^>]*>|\S+)")
HEADING = re.compile(r"^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
HTML_ANCHOR = re.compile(r"<a\s+(?:name|id)=\"([^\"]+)\"|\sid=\"([^\"]+)\"")
FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
CODE_SPAN = re.compile(r"(`+)(.+?)\1")
SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")
PATH_SPAN = re.compile(r"^[A-Za-z0-9_.-]+(?:/[A-Za-z0-9_.-]+)*/?$")


def named_paths(line):
    """The repository-looking paths named in `line`'s code spans: at least one '/', nothing but path characters."""
    for match in CODE_SPAN.finditer(line):
        span = match.group(2).strip()
        if "/" in span and PATH_SPAN.match(span) and not span.startswith(("./", "../")):
            yield span


def markdown_files(root):
    for directory, subdirs, files in os.walk(root):
        in_fuzz = os.path.basename(directory) == "fuzz"
        subdirs[:] = sorted(
            d
            for d in subdirs
            if not d.startswith(".") and d not in SKIP_DIRS and not (in_fuzz and d in SKIP_UNDER_FUZZ)
        )
        for name in sorted(files):
            if name.endswith(".md"):
                yield os.path.join(directory, name)


def prose_lines(text):
    """(line number, line, line with its code spans blanked) for each line outside fenced code blocks."""
    fence = None
    for number, line in enumerate(text.splitlines(), 1):
        match = FENCE.match(line)
        if fence is None:
            if match:
                fence = match.group(1)
                continue
            yield number, line, CODE_SPAN.sub(lambda m: " " * len(m.group(0)), line)
        elif match and match.group(1)[0] == fence[0] and len(match.group(1)) >= len(fence):
            fence = None


def slug(heading):
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link's text only
    text = re.sub(r"<[^>]+>", "", text)  # inline HTML
    text = text.replace("`", "").replace("*", "")
    text = re.sub(r"(?<!\w)_+|_+(?!\w)", "", text)  # _emphasis_, not snake_case
    text = re.sub(r"[^\w\- ]", "", text.lower())
    return text.replace(" ", "-")


anchor_cache = {}


def anchors(path):
    if path not in anchor_cache:
        found, seen = set(), {}
        with open(path, encoding="utf-8") as file:
            text = file.read()
        for _, line, prose in prose_lines(text):
            for match in HTML_ANCHOR.finditer(prose):
                found.add(match.group(1) or match.group(2))
            heading = HEADING.match(line)
            if heading:
                base = slug(heading.group(2))
                count = seen.get(base, 0)
                seen[base] = count + 1
                found.add(base if count == 0 else f"{base}-{count}")
        anchor_cache[path] = found
    return anchor_cache[path]


def broken(root, source, target):
    """Whether `target`, linked from the file `source`, does not resolve."""
    if target.startswith("<") and target.endswith(">"):
        target = target[1:-1]
    if not target or SCHEME.match(target):
        return False
    path, _, anchor = target.partition("#")
    path = unquote(path)
    if not path:
        resolved = source
    elif path.startswith("/"):
        resolved = os.path.join(root, path.lstrip("/"))
    else:
        resolved = os.path.join(os.path.dirname(source), path)
    resolved = os.path.normpath(resolved)
    if not os.path.exists(resolved):
        return True
    if anchor and resolved.endswith(".md") and os.path.isfile(resolved):
        return unquote(anchor).lower() not in anchors(resolved)
    return False


def main():
    root = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), ".."))
    top = set(os.listdir(root))
    files = links = bad = 0
    for source in markdown_files(root):
        files += 1
        with open(source, encoding="utf-8") as file:
            text = file.read()
        name = os.path.relpath(source, root)
        for number, line, prose in prose_lines(text):
            for path in named_paths(line):
                first = path.split("/", 1)[0]
                if first in top and first not in SKIP_DIRS:
                    links += 1
                    if not os.path.exists(os.path.join(root, path.rstrip("/"))):
                        bad += 1
                        print(f"{name}:{number}: names a path that does not exist: {path}")
            targets = [m.group(1) for m in INLINE.finditer(prose)]
            reference = REFERENCE.match(prose)
            if reference:
                targets.append(reference.group(1))
            for target in targets:
                links += 1
                if broken(root, source, target):
                    bad += 1
                    print(f"{name}:{number}: broken link {target}")
    if bad:
        print(f"{bad} of {links} links and named paths broken in {files} Markdown files", file=sys.stderr)
        return 1
    print(f"{links} links and named paths in {files} Markdown files: all resolve")
    return 0


if __name__ == "__main__":
    sys.exit(main())
