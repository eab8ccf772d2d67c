"""Simtrace CSV files read file by file on a thread pool (`read_simtrace_files`, `read_simtrace_csvs`, and `load`
on a folder) give exactly what Python's own csv module reads from the same text, for every irregular file a
real folder can hold: CRLF line ends, quoted continuous actions, a missing final newline, blank lines, a
byte-order mark, a header-only file, a file of an older width, gzip. A truncated last line or an empty file is
an error naming the file and the line."""

from __future__ import annotations

import csv
import io
import math
import re

import numpy as np
import pytest

from racerlab.analysis import load
from racerlab.logs import LogFileError
from racerlab.logs.read import RAW_COLUMNS, read_simtrace_csvs, read_simtrace_files

from .samples import HEADER_17, HEADER_19, csv_text, rows, write

# the CSV header's names for the frame's, written out here rather than taken from the reader
RENAME = {"X": "x", "Y": "y", "steer": "steering_angle", "throttle": "speed", "all_wheels_on_track": "on_track"}
INTS = {"episode", "steps", "closest_waypoint"}
BOOLS = {"done", "on_track"}


def reference(text: str) -> dict[str, list]:
    """The frame columns of one CSV text, read with the csv module and float()/int() field by field."""
    records = [r for r in csv.reader(io.StringIO(text.lstrip("\ufeff"), newline="")) if r]
    header = [RENAME.get(h, h) for h in records[0]]
    out: dict[str, list] = {c: [] for c in RAW_COLUMNS}
    for record in records[1:]:
        values = dict(zip(header, record, strict=True))
        for col in RAW_COLUMNS:
            v = values.get(col)
            if v is None:
                out[col].append(None if col == "episode_status" else math.nan)
            elif col in INTS:
                out[col].append(int(v))
            elif col in BOOLS:
                out[col].append(v == "True")
            elif col == "action":
                out[col].append(int(v) if re.fullmatch(r"\s*-?\d+\s*", v) else -1)
            elif col == "episode_status":
                out[col].append(v)
            else:
                out[col].append(float(v))
    return out


def assert_matches(table, texts: list[str]) -> None:
    expected: dict[str, list] = {c: [] for c in RAW_COLUMNS}
    for text in texts:
        for c, values in reference(text).items():
            expected[c] += values
    assert table.column_names == list(RAW_COLUMNS)
    got = table.to_pydict()
    for c in RAW_COLUMNS:
        if c in INTS or c in BOOLS or c in ("action", "episode_status"):
            assert got[c] == expected[c], c
        else:
            np.testing.assert_array_equal(np.array(got[c], float), np.array(expected[c], float), err_msg=c)


def irregular_texts() -> list[str]:
    return [
        csv_text([0, 1]),                                                   # plain 19 fields
        csv_text([2]).replace("\n", "\r\n"),                                # Windows line ends
        csv_text([3], action='"[0.5, 1.2]"'),                               # old continuous action, quoted
        csv_text([4], action="[-12.5 2.0]"),                                # continuous action since 2023
        csv_text([5, 6]).rstrip("\n"),                                      # no final newline
        HEADER_19 + "\n",                                                   # header only: no rows
        "\ufeff" + csv_text([7]),                                           # byte-order mark
        csv_text([8, 9], HEADER_17, 17),                                    # an older, narrower file
        HEADER_19 + "\n" + rows(19, 10)[0] + "\n\n" + "\n".join(rows(19, 10)[1:]) + "\n\n",  # blank lines
        csv_text([11]).replace(",3,0.", ",3.0,0."),                         # integer action written as a float
        HEADER_19 + "\n" + "\n".join(rows(19, 12) + rows(19, 13, '"[1.0, 2.0]"')) + "\n",  # discrete, then not
        csv_text([14]),
    ]


@pytest.mark.parametrize("threads", [True, False])
def test_files_read_one_by_one_equal_the_csv_module(tmp_path, threads):
    texts = irregular_texts()
    paths = [write(tmp_path / f"{i}-iteration.csv", t) for i, t in enumerate(texts)]
    paths[5] = write(tmp_path / "5-iteration.csv.gz", texts[5])
    names = [str(p) for p in paths]
    table, counts = read_simtrace_files(names, names, threads)
    assert counts.tolist() == [len(reference(t)["episode"]) for t in texts] == [6, 3, 3, 3, 6, 0, 3, 6, 3, 3, 6, 3]
    assert_matches(table, texts)
    blobs, blob_counts = read_simtrace_csvs([(n, p.read_bytes()) for n, p in zip(names, paths, strict=True)], threads)
    assert blob_counts.tolist() == counts.tolist()
    assert_matches(blobs, texts)


def test_load_of_an_irregular_folder_equals_the_csv_module(tmp_path):
    texts = irregular_texts()
    folder = tmp_path / "model"
    for i, t in enumerate(texts):
        write(folder / "training-simtrace" / f"{i}-iteration.csv", t)
    df = load(folder, cache=False)
    one_thread = load(folder, cache=False, threads=False)
    assert df.equals(one_thread) and len(df) == 45
    ref = reference(texts[2])
    assert df["action"].tolist()[9:12] == [-1] * 3 and df["steering_angle"].tolist()[9:12] == ref["steering_angle"]
    assert df["iteration"].tolist() == np.repeat(np.arange(12), [6, 3, 3, 3, 6, 0, 3, 6, 3, 3, 6, 3]).tolist()
    assert df.loc[df["iteration"] == 7, "wall_clock"].isna().all()
    assert df["unique_episode"].tolist() == np.repeat(np.arange(15), 3).tolist()


def test_a_truncated_last_line_names_the_file_and_line(tmp_path):
    good = write(tmp_path / "0-iteration.csv", csv_text([0]))
    cut = csv_text([1])
    bad = write(tmp_path / "1-iteration.csv", cut[:cut.rindex(",1700000000") - 30])  # a write cut short
    for threads in (True, False):
        with pytest.raises(LogFileError, match=r"1-iteration\.csv:4: expected 19 fields, got 1[0-9]: '1,3,"):
            read_simtrace_files([str(good), str(bad)], [str(good), str(bad)], threads)
    with pytest.raises(LogFileError, match=r"1-iteration\.csv:4: expected 19 fields"):
        load(tmp_path, cache=False)


def test_an_empty_file_names_the_file(tmp_path):
    good = write(tmp_path / "0-iteration.csv", csv_text([0]))
    empty = write(tmp_path / "1-iteration.csv", "")
    with pytest.raises(LogFileError, match=r"1-iteration\.csv:1: not a simtrace CSV header"):
        read_simtrace_files([str(good), str(empty)], [str(good), str(empty)])


def test_a_bad_value_names_the_file_and_line(tmp_path):
    texts = [csv_text([0]), csv_text([1, 2]).replace("True,1.5000", "maybe,1.5000", 1)]
    paths = [str(write(tmp_path / f"{i}-iteration.csv", t)) for i, t in enumerate(texts)]
    with pytest.raises(LogFileError, match=r"1-iteration\.csv:4: all_wheels_on_track is not True/False \('maybe'\)"):
        read_simtrace_files(paths, paths)
