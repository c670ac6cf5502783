"""benchmarks.stress_table: docs/robustness.md's stress table is what the committed records print, and a
page whose table no longer matches its records is caught and rewritten."""

import shutil

import pytest

from benchmarks import stress_table as st


@pytest.fixture
def copied(tmp_path, monkeypatch):
    """The committed records and page, copied so that the test may change them."""
    data, page = tmp_path / "stress", tmp_path / "robustness.md"
    shutil.copytree(st.DATA, data)
    shutil.copy(st.PAGE, page)
    monkeypatch.setattr(st, "DATA", data)
    monkeypatch.setattr(st, "PAGE", page)
    return data, page


def test_the_committed_table_is_what_its_records_print(copied, capsys):
    assert st.main(["--check"]) == 0
    data, page = copied
    names = sorted(p.stem for p in data.glob("*.json") if p.stem != "expert")
    assert all(f"| {name} |" in page.read_text() for name in names)


def test_a_record_removed_or_added_makes_the_page_stale_until_rewritten(copied, capsys):
    data, page = copied
    before = page.read_text()
    gone = sorted(data.glob("v1-*.json"))[0]
    gone.unlink()
    assert st.main(["--check"]) == 1 and "differs from its data" in capsys.readouterr().out
    assert page.read_text() == before  # a check writes nothing
    assert st.main(["--write"]) == 0
    after = page.read_text()
    assert f"| {gone.stem} |" not in after and st.main(["--check"]) == 0
    assert after.split(st.BEGIN)[0] == before.split(st.BEGIN)[0]  # only the block changed
    assert after.split(st.END)[1] == before.split(st.END)[1]


def test_a_page_without_its_markers_is_refused(copied):
    _, page = copied
    page.write_text(page.read_text().replace(st.END, ""))
    with pytest.raises(SystemExit, match="needs one"):
        st.main(["--check"])
