"""aerotri.core.textio.read_record: a versioned report record or one InputError naming the file and the record."""

from __future__ import annotations

import pytest

from aerotri.core.errors import InputError
from aerotri.core.textio import read_record, record_error

WHAT = "strip check (strips.json)"


@pytest.mark.parametrize("text, words", [
    ("{not json", r"strips.json:1: not valid JSON \(.*column 2\); the strip check \(strips.json\) is corrupt or truncated"),
    ('{"a": 1,\n', r"strips.json:2: not valid JSON .*the strip check \(strips.json\) is corrupt"),
    ("[1, 2]", r"strips.json: not a strip check \(strips.json\): a JSON array, expected an object"),
    ('"text"', r"strips.json: not a strip check \(strips.json\): a JSON string, expected an object"),
    ('{"schema_version": 3}', r"strips.json: not a strip check \(strips.json\) of schema version 2 or older \(schema_version 3\)"),
    ('{"schema_version": "1"}', r"not a strip check \(strips.json\) of schema version 2 or older \(schema_version \"1\"\)"),
    ('{"schema_version": true}', r"of schema version 2 or older \(schema_version true\)"),
    ("\ufeff\x00", r"strips.json:1: binary data .*expected a UTF-8 strip check \(strips.json\)"),
])
def test_what_is_not_a_record_is_one_input_error_naming_the_file(tmp_path, text, words):
    path = tmp_path / "strips.json"
    path.write_text(text)
    with pytest.raises(InputError, match=words) as e:
        read_record(path, WHAT, 2)
    assert str(e.value).startswith(str(path))


def test_missing_file_and_folder_name_the_record_expected(tmp_path):
    with pytest.raises(InputError, match=r"strips.json: file not found, expected a strip check \(strips.json\)"):
        read_record(tmp_path / "strips.json", WHAT, 1)
    (tmp_path / "strips.json").mkdir()
    with pytest.raises(InputError, match=r"strips.json: is a folder, expected a strip check \(strips.json\)"):
        read_record(tmp_path / "strips.json", WHAT, 1)


def test_current_older_and_unnumbered_records_are_read_as_written(tmp_path):
    path = tmp_path / "strips.json"
    for text, record in (('{"schema_version": 2, "a": [1]}', {"schema_version": 2, "a": [1]}),
                         ('{"schema_version": 1}', {"schema_version": 1}),
                         ('\ufeff{"a": null}', {"a": None})):
        path.write_text(text, encoding="utf-8")
        assert read_record(path, WHAT, 2) == record


def test_record_error_names_the_file_the_record_and_the_field():
    try:
        {}["pairs"]
    except KeyError as exc:
        err = record_error("out/strips.json", WHAT, exc)
    assert str(err) == "out/strips.json: not a strip check (strips.json): KeyError 'pairs'"


def test_utf8_symbols_are_not_taken_for_gbk(tmp_path, caplog):
    """Trial s97 L3: our own orthority export's .prj (WKT2 with "Between 108°E and 114°E") re-imported warned of a
    GBK file, its two excerpts identical (they stopped before the degree sign). Symbols are UTF-8's own; GBK text
    read as UTF-8 by chance is still said, its excerpts where the readings part."""
    import logging

    from aerotri.core.textio import read_text

    prj = tmp_path / "ext_param.prj"
    prj.write_text('PROJCRS["CGCS2000 / 3-degree Gauss-Kruger CM 111E",BASEGEOGCRS["China Geodetic Coordinate '
                   'System 2000"],USAGE[AREA["China - between 109°30\'E and 112°30\'E"]]] ±0.5 µm 2²\n',
                   encoding="utf-8")
    with caplog.at_level(logging.WARNING, logger="aerotri"):
        assert "109°30" in read_text(prj)
    assert "GBK" not in caplog.text
    gbk = tmp_path / "levels.csv"
    gbk.write_bytes(("id,x,y,h\n" + "A" * 60 + ",水准G1,1,2\n").encode("gbk"))
    with caplog.at_level(logging.WARNING, logger="aerotri"):
        read_text(gbk)
    assert "reads as UTF-8 'AAAAAAAAA,ˮ" in caplog.text and "as GBK 'AAAAAAAAA,水准G1" in caplog.text, caplog.text
