#!/usr/bin/env python3
"""Fails when the source files of a crate import each other in a cycle.

For every crate under `crates/`, each file of `src/` is a module (`src/a.rs` or `src/a/mod.rs`
is `a`, `src/a/b.rs` is `a::b`). A file depends on another when it names a path into it:
`use crate::…`, `use super::…`, `use self::…` (brace groups expanded) or an inline
`crate::a::b` / `super::x` path. A path resolves to the deepest module file it names. Edges
between a module and its own ancestors or descendants are not counted (a parent declares and
re-exports its children; a child may use what its parent re-exports), nor is test code (files
named `tests.rs`, files under a `tests/` folder of `src/`, and everything from the first
`#[cfg(test)]` line of a file on). Every strongly connected set of two or more files is printed
and makes the exit code 1.

Usage: python3 scripts/check-cycles.py [REPO_ROOT]
"""

import os
import re
import sys


def module_of(src_dir, path):
    rel = os.path.relpath(path, src_dir)[: -len(".rs")]
    parts = rel.split(os.sep)
    if parts[-1] == "mod":
        parts = parts[:-1]
    if parts in (["lib"], ["main"]):
        return ()
    return tuple(parts)


def strip_comments(text):
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    return "\n".join(line.split("//", 1)[0] for line in text.splitlines())


def non_test_part(text):
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.strip().startswith("#[cfg(test)]"):
            return "\n".join(lines[:i])
    return text


def expand_use(tree):
    """Expands `a::{b, c::{d, e}}` into ['a::b', 'a::c::d', 'a::c::e']."""
    tree = tree.strip()
    brace = tree.find("{")
    if brace < 0:
        return [tree]
    prefix = tree[:brace]
    body = tree[brace + 1 : tree.rfind("}")]
    items, depth, cur = [], 0, ""
    for ch in body:
        if ch == "," and depth == 0:
            items.append(cur)
            cur = ""
            continue
        depth += ch == "{"
        depth -= ch == "}"
        cur += ch
    items.append(cur)
    out = []
    for item in items:
        if item.strip():
            out.extend(prefix + sub for sub in expand_use(item))
    return out


def resolve(path, here, modules):
    """The module a `crate::…`/`super::…`/`self::…` path points into, or None."""
    parts = [p.strip() for p in path.split("::") if p.strip()]
    parts = [p.split(" as ")[0].strip() for p in parts]
    if not parts:
        return None
    if parts[0] == "crate":
        base, rest = (), parts[1:]
    elif parts[0] in ("super", "self"):
        base = here
        rest = parts
        while rest and rest[0] in ("super", "self"):
            if rest[0] == "super":
                base = base[:-1]
            rest = rest[1:]
    else:
        return None
    best = base if base in modules else None
    cur = base
    for p in rest:
        cur = cur + (p,)
        if cur in modules:
            best = cur
    return best


def crate_edges(src_dir):
    files = {}
    for root, dirs, names in os.walk(src_dir):
        rel_root = os.path.relpath(root, src_dir).split(os.sep)
        if "tests" in rel_root:
            continue
        for name in names:
            if name.endswith(".rs") and name != "tests.rs":
                path = os.path.join(root, name)
                files[module_of(src_dir, path)] = path
    modules = set(files)
    edges = {m: set() for m in modules}
    for mod, path in files.items():
        with open(path, encoding="utf-8") as f:
            text = non_test_part(strip_comments(f.read()))
        paths = []
        for m in re.finditer(r"\buse\s+([^;]+);", text):
            paths.extend(expand_use(m.group(1)))
        paths.extend(re.findall(r"\b(?:crate|super|self)(?:::\w+)+", text))
        for p in paths:
            target = resolve(p, mod, modules)
            if target is None or target == mod:
                continue
            if target[: len(mod)] == mod or mod[: len(target)] == target:
                continue
            edges[mod].add(target)
    return files, edges


def strongly_connected(edges):
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            out.append(comp)

    sys.setrecursionlimit(10000)
    for v in sorted(edges):
        if v not in index:
            visit(v)
    return [c for c in out if len(c) > 1]


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..")
    crates_dir = os.path.join(root, "crates")
    failures = 0
    for crate in sorted(os.listdir(crates_dir)):
        src = os.path.join(crates_dir, crate, "src")
        if not os.path.isdir(src):
            continue
        files, edges = crate_edges(src)
        for comp in strongly_connected(edges):
            failures += 1
            names = sorted(os.path.relpath(files[m], root) for m in comp)
            print(f"import cycle in {crate}: " + " <-> ".join(names))
            for m in sorted(comp):
                inside = sorted(os.path.relpath(files[t], root) for t in edges[m] if t in comp)
                print(f"    {os.path.relpath(files[m], root)} uses {', '.join(inside)}")
    if failures:
        print(f"{failures} import cycle(s) between files")
        return 1
    print("no import cycle between the files of any crate")
    return 0


if __name__ == "__main__":
    sys.exit(main())
