"""The one bounded reader (values/files.py): only regular files, a size cap checked before reading, nesting
and integers bounded after parsing, every refusal one line ``<file>: <key>: <message>``, and nothing that
can hang (a FIFO) or read without end (/dev/zero behind a symlink)."""

from __future__ import annotations

import json

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ddpc_codegen.errors import ManifestError
from ddpc_codegen.values.files import (MAX_DEPTH, check_nesting, checked_input_path, checked_output_file,
                                       checked_output_folder,
                                       load_json_bounded, load_toml_bounded, nesting_depth, parse_json, parse_toml,
                                       read_bytes_bounded, read_text_bounded, text_nesting_depth)
from support.bounded import bounded_refusal, make_fifo, needs_dev_zero, needs_fifo, refusal

# ----------------------------------------------------------------------------- what may be read
@needs_fifo
@pytest.mark.parametrize("reader", [
    lambda p: checked_input_path(p, "steering config"),
    lambda p: read_text_bounded(p, "steering config"),
    lambda p: load_toml_bounded(p, "steering config"),
    lambda p: load_json_bounded(p, "steering config"),
])
def test_a_fifo_is_refused_without_waiting_for_a_writer(tmp_path, reader):
    path, unblock = make_fifo(tmp_path / "pipe.toml")
    msg = bounded_refusal(reader, path, unblock=unblock)
    assert msg == f"{path}: steering config: is a FIFO (named pipe), not a regular file"


@needs_dev_zero
def test_dev_zero_behind_a_symlink_is_a_device_and_never_read(tmp_path):
    link = tmp_path / "manifest.json"
    link.symlink_to("/dev/zero")
    msg = bounded_refusal(lambda: load_json_bounded(link, "manifest", error=ManifestError), error=ManifestError)
    assert msg == f"{link}: manifest: is a character device, not a regular file"


def test_missing_files_and_folders_are_named(tmp_path):
    assert refusal(read_text_bounded, tmp_path / "absent.toml", "sweep spec") == \
        f"{tmp_path / 'absent.toml'}: sweep spec: does not exist"
    assert refusal(read_text_bounded, tmp_path, "sweep spec") == f"{tmp_path}: sweep spec: is a directory, not a regular file"
    dangling = tmp_path / "dangling.toml"
    dangling.symlink_to(tmp_path / "nowhere")
    assert refusal(checked_input_path, dangling, "robot profile").endswith("robot profile: does not exist")


def test_the_size_cap_is_checked_before_reading(tmp_path):
    big = tmp_path / "big.json"
    big.write_text(" " * 2000 + "{}")
    assert refusal(load_json_bounded, big, "prefilter", 1000) == \
        f"{big}: prefilter: 2002 bytes, more than a prefilter may have (1000 bytes)"
    assert refusal(checked_input_path, big, "feed-forward table", 1000).endswith("2002 bytes, more than a "
                                                                                  "feed-forward table may have (1000 bytes)")
    assert load_json_bounded(big, "prefilter", 2002) == {}


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=300), cap=st.integers(0, 300))
def test_read_bytes_bounded_returns_the_file_or_refuses_it(tmp_path, data, cap):
    path = tmp_path / "f.bin"
    path.write_bytes(data)
    if len(data) <= cap:
        assert read_bytes_bounded(path, "input", cap) == data
    else:
        assert refusal(read_bytes_bounded, path, "input", cap) == \
            f"{path}: input: {len(data)} bytes, more than a input may have ({cap} bytes)"


def test_text_must_be_utf8(tmp_path):
    path = tmp_path / "latin1.csv"
    path.write_bytes(b"t,x,z\n0,0,\xe9\n")
    assert refusal(read_text_bounded, path, "trajectory file") == \
        f"{path}: trajectory file: is not UTF-8 text (byte 10 is 0xe9)"
    assert refusal(parse_json, b"\xff\xfe{", "m.json", "manifest").startswith("m.json: manifest: is not valid JSON")


# ----------------------------------------------------------------------------- nesting and numbers
def test_text_nesting_depth_counts_brackets_outside_strings():
    assert text_nesting_depth('{"a": [1, [2, {"b": "[[[["}]]}') == 4
    assert text_nesting_depth("x = ['[', \"]\\\"[\"]") == 1
    assert text_nesting_depth("") == 0


_TREES = st.recursive(st.none() | st.integers() | st.text(max_size=4), lambda c: st.lists(c, max_size=3)
                      | st.dictionaries(st.text(max_size=3), c, max_size=3), max_leaves=20)


@given(_TREES)
def test_both_depths_match_the_structure(obj):
    def depth(o):
        if isinstance(o, list):
            return 1 + max((depth(v) for v in o), default=0)
        if isinstance(o, dict):
            return 1 + max((depth(v) for v in o.values()), default=0)
        return 0

    assert text_nesting_depth(json.dumps(obj)) == nesting_depth(obj) == depth(obj)


@pytest.mark.parametrize("parse, text, src", [
    (parse_json, "[" * 100_000 + "]" * 100_000, "deep.json"),
    (parse_toml, "a = " + "[" * 100_000 + "]" * 100_000, "deep.toml"),
    (parse_toml, "a = " + "{b = " * 100_000 + "1" + "}" * 100_000, "deep.toml"),
])
def test_deep_nesting_is_refused_not_a_recursion_error(parse, text, src):
    assert refusal(parse, text, src, "steering config") == \
        f"{src}: steering config: nested 100000 levels deep, more than a steering config may be ({MAX_DEPTH})"


@given(st.integers(1, 60))
def test_nesting_within_the_cap_parses_and_beyond_it_names_the_key(levels):
    text = '{"cost": {"R": ' + "[" * levels + "1" + "]" * levels + "}}"
    if levels + 2 <= MAX_DEPTH:
        assert nesting_depth(parse_json(text, "c.json", "config")) == levels + 2
    else:
        msg = refusal(parse_json, text, "c.json", "config")
        assert msg.startswith("c.json: cost.R[0][0]") and msg.endswith(
            f"nested more than {MAX_DEPTH} levels deep, more than a config may be"), msg


@given(st.integers(309, 4000))
def test_integers_beyond_float_range_are_named(digits):
    big = "9" * digits
    assert refusal(parse_toml, f"[prefilter]\ngain = [1, {big}]\n", "p.toml", "prefilter") == \
        f"p.toml: prefilter.gain[1]: an integer of {digits} digits, beyond the range of any number a prefilter holds " \
        "(±1.8e308)"
    assert refusal(parse_json, f'{{"prefilter": {{"gain": {big}}}}}', "p.json", "prefilter").startswith(
        "p.json: prefilter.gain: an integer of")
    assert refusal(check_nesting, int(big), "x", "seed").startswith("x: seed: an integer of")


def test_what_the_parsers_refuse_is_one_line():
    assert refusal(parse_toml, "a = " + "1" * 5000, "t.toml", "sweep spec").startswith(
        "t.toml: sweep spec: is not valid TOML: Exceeds the limit (4300 digits)")
    assert refusal(parse_toml, "[x\n", "t.toml", "sweep spec").startswith("t.toml: sweep spec: is not valid TOML:")
    assert refusal(parse_json, "{", "j.json", "manifest").startswith("j.json: manifest: is not valid JSON:")


def test_ordinary_values_pass_unchanged():
    assert parse_toml('[a]\nb = [[1, 2], [3]]\nc = 1e308\nd = 123456789012345678901234567890\n', "t", "x") == \
        {"a": {"b": [[1, 2], [3]], "c": 1e308, "d": 123456789012345678901234567890}}
    assert parse_json('{"x": NaN}', "j", "x")["x"] != 0


@needs_fifo
def test_an_output_folder_must_be_a_folder_or_makeable(tmp_path):
    fifo, _ = make_fifo(tmp_path / "out")
    assert refusal(checked_output_folder, fifo, "--out") == f"{fifo}: --out: is a FIFO (named pipe), not a folder"
    assert refusal(checked_output_folder, fifo / "a" / "b", "--out") == \
        f"{fifo / 'a' / 'b'}: --out: {fifo} is a FIFO (named pipe), not a folder"
    assert checked_output_folder(tmp_path / "new" / "deeper", "--out") == tmp_path / "new" / "deeper"
    assert checked_output_folder(tmp_path, "--out") == tmp_path


# ----------------------------------------------------------------------------- what may be written
@needs_fifo
def test_an_output_file_is_absent_or_a_regular_file_replaced_only_with_overwrite(tmp_path):
    """A result file: never a FIFO, device or folder; an existing one only with ``overwrite``; the probe leaves
    nothing behind; the resolved path comes back (two names of one file compare equal)."""
    from ddpc_codegen.errors import ConfigError

    new = tmp_path / "new.json"
    assert checked_output_file(tmp_path / "." / "new.json", "--summary") == new.resolve() and not new.exists()
    new.write_text("{}")
    with pytest.raises(ConfigError, match="new.json: --summary: exists; pass --overwrite to replace it"):
        checked_output_file(new, "--summary")
    assert checked_output_file(new, "--summary", overwrite=True) == new.resolve()
    fifo = tmp_path / "p.json"
    make_fifo(fifo)
    (tmp_path / "d").mkdir()
    for path, kind in ((fifo, "a FIFO"), (tmp_path / "d", "a directory"), ("/dev/null", "a character device")):
        with pytest.raises(ConfigError, match=f"is {kind}"):
            checked_output_file(path, "--log", overwrite=True)
    with pytest.raises(ConfigError, match="folder .* does not exist"):
        checked_output_file(tmp_path / "no" / "x.json", "--log")
