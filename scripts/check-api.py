#!/usr/bin/env python3
"""The public API gate: the items of the `dynapix` crate's rustdoc index
(`target/doc/dynapix/all.html`, built by `cargo doc --workspace --no-deps`) must be exactly
those listed in `scripts/dynapix-api.txt` (one `kind path` per line). A new public item, or one
that went, is then a visible change of that file in review. After a deliberate change:

    cargo doc -p dynapix --no-deps && python3 scripts/check-api.py --update
"""
import html
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
INDEX = ROOT / "target" / "doc" / "dynapix" / "all.html"
LIST = ROOT / "scripts" / "dynapix-api.txt"


def items() -> list[str]:
    if not INDEX.is_file():
        sys.exit(f"check-api: {INDEX} is missing; run `cargo doc -p dynapix --no-deps` first")
    text = INDEX.read_text(encoding="utf-8")
    out = []
    for href, name in re.findall(r'<li><a href="([^"]+)">([^<]+)</a></li>', text):
        kind = href.rsplit("/", 1)[-1].split(".", 1)[0]
        out.append(f"{kind} {html.unescape(name)}")
    if not out:
        sys.exit(f"check-api: no items found in {INDEX} (rustdoc's layout changed?)")
    return out


def main() -> None:
    now = items()
    if "--update" in sys.argv[1:]:
        LIST.write_text("".join(f"{i}\n" for i in now), encoding="utf-8")
        print(f"check-api: wrote {len(now)} items to {LIST.relative_to(ROOT)}")
        return
    want = [l.strip() for l in LIST.read_text(encoding="utf-8").splitlines() if l.strip()]
    added = sorted(set(now) - set(want))
    gone = sorted(set(want) - set(now))
    if added or gone:
        for i in added:
            print(f"new public item: {i}")
        for i in gone:
            print(f"public item gone: {i}")
        sys.exit(
            f"check-api: the public API of `dynapix` ({len(now)} items) differs from "
            f"{LIST.relative_to(ROOT)} ({len(want)}); if deliberate, run "
            "`python3 scripts/check-api.py --update` and commit the list"
        )
    print(f"check-api: {len(now)} public items, as listed")


if __name__ == "__main__":
    main()
