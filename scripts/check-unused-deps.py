#!/usr/bin/env python3
"""Fails when a crate of the workspace declares a dependency its sources never name.

cargo-udeps needs a nightly toolchain, so this is a plain text check. For every crate under
`crates/`, each entry of `[dependencies]` (including target-specific tables) must be named in
that crate's `src/`, each entry of `[dev-dependencies]` anywhere in its sources (`src/`, `tests/`,
`benches/`, `examples/`), each entry of `[build-dependencies]` in `build.rs`; named means
`name::…`, `use name` or `extern crate name`, with `-` in the name read as `_`. Comments do not
count. A dependency named only by tests, benches or examples belongs in `[dev-dependencies]`.
Every entry of the root `[workspace.dependencies]` must be used by some crate.

A dependency that is needed without being named in the code (for example one pulled in only
to switch on a feature of another crate) goes in EXCEPTIONS below, with the reason.

Usage: python3 scripts/check-unused-deps.py [REPO_ROOT]
"""

import os
import re
import sys
import tomllib

# (crate, dependency) -> why the dependency is needed although no source file names it.
EXCEPTIONS = {}

TABLES = ("dependencies", "dev-dependencies", "build-dependencies")


def declared(manifest):
    """(table, dependency key) of every dependency entry of a parsed Cargo.toml."""
    out = []
    for table in TABLES:
        out += [(table, k) for k in manifest.get(table, {})]
    for target, spec in manifest.get("target", {}).items():
        for table in TABLES:
            out += [(f"target.{target}.{table}", k) for k in spec.get(table, {})]
    return out


def source_files(crate_dir, subs=("src", "tests", "benches", "examples")):
    for sub in subs:
        for dirpath, _, files in os.walk(os.path.join(crate_dir, sub)):
            for name in files:
                if name.endswith(".rs"):
                    yield os.path.join(dirpath, name)
    build = os.path.join(crate_dir, "build.rs")
    if "build.rs" in subs and os.path.isfile(build):
        yield build


def strip_comments(text):
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    return "\n".join(line.split("//", 1)[0] for line in text.splitlines())


def main(argv):
    root = argv[1] if len(argv) > 1 else os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    crates_dir = os.path.join(root, "crates")
    unused = []
    used_by_workspace = set()
    for crate in sorted(os.listdir(crates_dir)):
        crate_dir = os.path.join(crates_dir, crate)
        manifest_path = os.path.join(crate_dir, "Cargo.toml")
        if not os.path.isfile(manifest_path):
            continue
        with open(manifest_path, "rb") as f:
            manifest = tomllib.load(f)
        def code_of(subs):
            return "\n".join(
                strip_comments(open(p, encoding="utf-8").read())
                for p in source_files(crate_dir, subs)
            )

        code = {
            "dependencies": code_of(("src",)),
            "dev-dependencies": code_of(("src", "tests", "benches", "examples")),
            "build-dependencies": code_of(("build.rs",)),
        }
        for table, key in declared(manifest):
            used_by_workspace.add(key)
            if (crate, key) in EXCEPTIONS:
                continue
            name = re.escape(key.replace("-", "_"))
            pattern = rf"(?<![\w:]){name}::|\buse\s+{name}\b|\bextern\s+crate\s+{name}\b"
            if not re.search(pattern, code[table.rsplit(".", 1)[-1]]):
                where = {
                    "dependencies": "src/",
                    "dev-dependencies": "its sources",
                    "build-dependencies": "build.rs",
                }[table.rsplit(".", 1)[-1]]
                unused.append(f"{crate}: [{table}] {key} is not named in {where}")
    with open(os.path.join(root, "Cargo.toml"), "rb") as f:
        workspace = tomllib.load(f).get("workspace", {})
    for key in workspace.get("dependencies", {}):
        if key not in used_by_workspace:
            unused.append(f"[workspace.dependencies] {key} is used by no crate")
    for line in unused:
        print(line)
    if unused:
        print(f"{len(unused)} unused dependency entr{'y' if len(unused) == 1 else 'ies'}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
