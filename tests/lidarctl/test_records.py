"""The report records of lidarctl (strips.json, adjust.json, corners.json, the check-plan --json file,
classification_eval.json) read
by one reader: what is not one is one InputError of one form naming the file and the record expected."""

from __future__ import annotations

import pytest

from aerotri.core.errors import InputError
from lidarctl.corners.roof_corners import read_corner_summary
from lidarctl.checks.classes import read_filter_test
from lidarctl.checks.plan import read_plan_check
from lidarctl.strips.adjust import read_strip_adjustment
from lidarctl.strips.check import read_strip_check

READERS = [(read_strip_check, "strips.json", r"strip check \(strips.json\)"),
           (read_strip_adjustment, "adjust.json", r"strip adjustment \(adjust.json\)"),
           (read_corner_summary, "corners.json", r"corner summary \(corners.json\)"),
           (read_plan_check, "plan.json", r"plan check \(check-plan --json\)"),
           (read_filter_test, "classification_eval.json", r"classification evaluation \(classification_eval.json\)")]


@pytest.mark.parametrize("read, name, what", READERS, ids=[r[1] for r in READERS])
def test_what_is_not_a_record_names_the_file_and_the_record(tmp_path, read, name, what):
    path = tmp_path / name
    with pytest.raises(InputError, match=f"{name}: file not found, expected a {what}"):
        read(path)
    for text, words in (('{"schema_version": 1,\n  "x": ', f"{name}:2: not valid JSON .*the {what} is corrupt or truncated"),
                        ("[]", f"{name}: not a {what}: a JSON array, expected an object"),
                        ('{"schema_version": 2}', f"{name}: not a {what} of schema version 1 or older \\(schema_version 2\\)"),
                        ('{"schema_version": 1}', f"{name}: not a {what}: KeyError '"),
                        ('{"schema_version": 1, "settings": 3, "source": 3, "overall": 3}', f"{name}: not a {what}: ")):
        path.write_text(text)
        with pytest.raises(InputError, match=words) as e:
            read(path)
        assert str(e.value).startswith(str(path)) and "\n" not in str(e.value)
