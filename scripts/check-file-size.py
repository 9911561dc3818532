#!/usr/bin/env python3
"""Fails when a source file of a crate holds more than LIMIT lines of non-test code.

Every `.rs` file under `crates/*/src` is read. Test code does not count: files named
`tests.rs` or under a `tests/` folder of `src/`, and every item marked `#[cfg(test)]` (a test
module, or a helper function used only by tests), from its attribute to the end of its braces
or its `;`. Every other line counts, blank lines and comments included: they are what a reader
scrolls through. Each file over the limit is printed with its count and makes the exit code 1.

Usage: python3 scripts/check-file-size.py [--limit N] [REPO_ROOT]   (default limit 800)
"""

import os
import re
import sys

DEFAULT_LIMIT = 800


def is_test_file(rel_to_src):
    parts = rel_to_src.split(os.sep)
    return parts[-1] == "tests.rs" or "tests" in parts[:-1]


def strip_strings_and_comments(line):
    """The line with string/char literals and `//` comments blanked, for brace counting."""
    line = re.sub(r'"(?:\\.|[^"\\])*"', '""', line)
    line = re.sub(r"'(?:\\.|[^'\\])'", "''", line)
    return line.split("//", 1)[0]


def non_test_lines(text):
    """Number of lines of `text` outside `#[cfg(test)]` items."""
    lines = text.splitlines()
    count = 0
    i = 0
    while i < len(lines):
        if lines[i].strip().startswith("#[cfg(test)]"):
            # Skip the item the attribute applies to: up to the `;` or the brace that closes it.
            depth = 0
            opened = False
            j = i + 1
            if not lines[i].startswith((" ", "\t")):
                # A top-level item: rustfmt closes it with a `}` (or ends it with a `;`) at the
                # start of a line, whatever its string literals hold.
                while j < len(lines) and lines[j] != "}" and not (
                    j == i + 1 and lines[j].rstrip().endswith(";")
                ):
                    j += 1
                i = j + 1
                continue
            while j < len(lines):
                code = strip_strings_and_comments(lines[j])
                depth += code.count("{") - code.count("}")
                opened = opened or "{" in code
                if (opened and depth <= 0) or (not opened and code.rstrip().endswith(";")):
                    break
                j += 1
            i = j + 1
            continue
        count += 1
        i += 1
    return count


def main(argv):
    limit = DEFAULT_LIMIT
    args = list(argv[1:])
    if len(args) >= 2 and args[0] == "--limit":
        limit = int(args[1])
        args = args[2:]
    root = args[0] if args else os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    crates = os.path.join(root, "crates")
    over = []
    for crate in sorted(os.listdir(crates)):
        src = os.path.join(crates, crate, "src")
        for dirpath, _, files in os.walk(src):
            for name in sorted(files):
                if not name.endswith(".rs"):
                    continue
                path = os.path.join(dirpath, name)
                if is_test_file(os.path.relpath(path, src)):
                    continue
                with open(path, encoding="utf-8") as f:
                    n = non_test_lines(f.read())
                if n > limit:
                    over.append((n, os.path.relpath(path, root)))
    for n, path in sorted(over, reverse=True):
        print(f"{path}: {n} lines of non-test code (limit {limit})")
    if over:
        print(f"{len(over)} file(s) over {limit} lines of non-test code")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
