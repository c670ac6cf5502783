"""A generated block of a docs page: the text between its BEGIN/END markers, rewritten (`--write`) or
checked (`--check`) against what its data prints. Shared by the benchmarks that own such blocks."""

from __future__ import annotations

from pathlib import Path


def splice(page: str, body: str, begin: str, end: str, page_name: str, error: type[Exception] = ValueError) -> str:
    """`page` with the text between its markers replaced by `body`; a page without both markers, in order,
    is refused with `error` naming them."""
    if page.count(begin) != 1 or page.count(end) != 1 or page.index(begin) > page.index(end):
        raise error(f"{page_name}: needs one '{begin}' line and one '{end}' line after it")
    head, rest = page.split(begin, 1)
    return f"{head}{begin}\n\n{body}\n\n{end}{rest.split(end, 1)[1]}"


def write_or_check(path: Path, page: str, updated: str, check: bool, what: str, command: str) -> int:
    """`--check`: 0 when the page is `updated` already, else 1 naming `command`; otherwise write it."""
    if check:
        if updated != page:
            print(f"{path}: {what} differs from its data ({command} --write)")
            return 1
        print(f"{path}: {what} is what its data prints")
        return 0
    path.write_text(updated)
    print(f"rewrote {what} of {path}")
    return 0
