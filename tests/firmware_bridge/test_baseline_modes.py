"""The files the baseline modes fly on are refused before anything connects when they cannot be flown:
the probes of issue 28 (NaN / string gains, a 3-channel prefilter, a table of 1e6, a (10, 2, 2) table, NaN
dt, huge declared shapes) with their exact messages, and property tests that mutate every field of each
file kind: a ConfigError / ValueError naming the file, or a policy whose numbers are all finite."""

from __future__ import annotations

import io
import json
import math
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_bridge.baseline_modes import load_feedforward, load_prefilter
from firmware_bridge.bridge_config import BridgeConfig
from support.fuzz import fuzz_examples

SPAN = np.array([21.0, 1.0472])  # the default envelope: z in [-1, 20] m, pitch within +-30 deg
GOOD = {"gain": [0.98, 1.0], "offset": [0.01, 0.0], "lead": [60, 10], "dt": 0.005, "names": ["z_ref", "pitch_ref"],
        "residual_rms": [0.01, float("nan")], "r2": [0.99, 0.9]}


def _prefilter(tmp_path, **change) -> str:
    f = tmp_path / "pf.json"
    f.write_text(json.dumps({"prefilter": {**GOOD, **change}}))
    return str(f)


@pytest.mark.parametrize("change, msg", [
    ({"gain": [float("nan"), 1.0]}, r"pf.json: prefilter gain\[0\] must be a finite number in \[-1000, 1000\]; got nan"),
    ({"gain": ["1", "1"]}, r"pf.json: prefilter gain\[0\] must be a finite number .*; got '1'"),
    ({"gain": [0.0, 1.0]}, r"pf.json: prefilter gain must be at least 1e-3 in magnitude per channel"),
    ({"gain": [1.0, 1.0, 1.0], "offset": [0, 0, 0], "lead": [1, 1, 1], "names": [], "residual_rms": [], "r2": []},
     r"pf.json: the model has 3 channels; the loop has m=2"),
    ({"offset": [1e6, 0.0]}, r"pf.json: prefilter offset\[0\] must be a finite number in \[-10000, 10000\]; got 1000000.0"),
    ({"offset": [50.0, 0.0]}, r"pf.json: channel 0 shifts the reference by offset / gain = 51.02.*range of that reference \(21\)"),
    ({"lead": [1e9, 1]}, r"pf.json: prefilter lead\[0\] must be an integer in \[0, 2000\]; got 1000000000.0"),
    ({"lead": [1.5, 1]}, r"pf.json: prefilter lead\[0\] must be an integer"),
    ({"dt": 0.01}, r"pf.json: model tick 0.01 s does not match the bridge rate 200 Hz"),
    ({"dt": None}, r"pf.json: prefilter dt must be a finite number in \(0, 1\]; got None"),
    ({"colour": 1}, r"pf.json: prefilter colour is not a known key"),
])
def test_prefilter_probes_are_refused_precisely(tmp_path, change, msg):
    with pytest.raises(ValueError, match=msg):
        load_prefilter(_prefilter(tmp_path, **change), 200.0, 2, SPAN)


def test_prefilter_files_that_are_not_one(tmp_path):
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ValueError, match=r"deep.json: prefilter: nested 100000 levels deep, more than a prefilter may be \(32\)"):
        load_prefilter(str(deep), 200.0, 2)
    other = tmp_path / "other.json"
    other.write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"other.json: not a prefilter JSON file \(no 'prefilter' table\)"):
        load_prefilter(str(other), 200.0, 2)
    assert load_prefilter(_prefilter(tmp_path), 200.0, 2, SPAN).horizon == 61


def _npz(path, **arrays) -> str:
    np.savez(path, **arrays)
    return str(path)


def test_feedforward_probes_are_refused_precisely(tmp_path):
    cases = [
        (dict(delta=np.full((10, 2), 1e6), dt=0.005, clock="trajectory"),
         r"big.npz: delta column 0 reaches 1e\+06, more than the envelope's range of that reference \(21"),
        (dict(delta=np.zeros((10, 2, 2)), dt=0.005, clock="trajectory"),
         r"big.npz: delta must be \(N, m\) numbers with N <= 1000000 and m <= 16; got shape \(10, 2, 2\)"),
        (dict(delta=np.zeros((10, 2)), dt=np.nan, clock="trajectory"), r"big.npz: dt must be a finite number in \(0, 1\]; got nan"),
        (dict(delta=np.zeros((10, 2)), dt=0.005, clock=1), r"big.npz: clock must be one string; got shape \(\) of kind 'i'"),
        (dict(delta=np.array([[0.0, np.nan]]), dt=0.005, clock="trajectory"), r"big.npz: delta must be finite; row 0 column 1 is nan"),
        (dict(delta=np.array([["a", "b"]]), dt=0.005, clock="trajectory"), r"big.npz: delta must be \(N, m\) numbers"),
        (dict(dt=0.005, clock="trajectory"), r"big.npz: not a feed-forward table \(no 'delta' array\)"),
    ]
    for arrays, msg in cases:
        with pytest.raises(ValueError, match=msg):
            load_feedforward(_npz(tmp_path / "big.npz", **arrays), 200.0, 2, SPAN)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(ValueError, match=r"junk.npz: not a feed-forward table \(BadZipFile"):
        load_feedforward(str(junk), 200.0, 2)


def test_a_huge_declared_shape_is_refused_before_reading(tmp_path):
    """An npy header declaring 10^12 rows: refused from the header (nothing allocated)."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": (10**12, 2)})
    f = tmp_path / "huge.npz"
    with zipfile.ZipFile(f, "w") as zf:
        zf.writestr("delta.npy", buf.getvalue() + b"\0" * 64)
        zf.writestr("dt.npy", _npy(np.float64(0.005)))
        zf.writestr("clock.npy", _npy(np.str_("trajectory")))
    with pytest.raises(ValueError, match=r"huge.npz: delta must be \(N, m\) numbers .*got shape \(1000000000000, 2\)"):
        load_feedforward(str(f), 200.0, 2)


def _npy(a) -> bytes:
    b = io.BytesIO()
    np.save(b, a)
    return b.getvalue()


def test_bridge_config_refuses_the_table_before_connecting(tmp_path):
    f = _npz(tmp_path / "ff.npz", delta=np.full((10, 2), 1e6), dt=0.005, clock="trajectory")
    with pytest.raises(ValueError, match=r"--feedforward .*ff.npz: z_ref on the path reaches 1e\+06 m, outside the "
                                         r"envelope's upper bound 10 m"):
        BridgeConfig(mode="feedforward", feedforward=f)


# ----------------------------------------------------------------------------- properties
_VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**20, 10**20), st.booleans(),
                    st.none(), st.text(max_size=6), st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4),
                    st.lists(st.integers(-10**6, 10**6), max_size=4), st.lists(st.text(max_size=3), max_size=3),
                    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


@settings(max_examples=fuzz_examples(500), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(key=st.sampled_from(sorted(GOOD) + ["extra"]), value=_VALUES, drop=st.booleans())
def test_mutated_prefilters_are_refused_or_finite(tmp_path, key, value, drop):
    d = dict(GOOD)
    if drop:
        d.pop(key, None)
    else:
        d[key] = value
    f = tmp_path / "mut.json"
    f.write_text(json.dumps({"prefilter": d}))
    try:
        pol = load_prefilter(str(f), 200.0, 2, SPAN)
    except ValueError as e:  # ConfigError is one
        assert "mut.json" in str(e), str(e)
        return
    m = pol.model
    assert all(math.isfinite(v) for v in (*m.gain, *m.offset, *m.lead, m.dt))
    assert np.all(np.abs(np.asarray(m.offset) / np.asarray(m.gain)) <= SPAN)


_ARRAYS = st.one_of(
    st.builds(lambda shape, fill: np.full(shape, fill), st.tuples(st.integers(0, 4), st.integers(0, 4)),
              st.floats(allow_nan=True, allow_infinity=True)),
    st.builds(lambda shape: np.zeros(shape), st.lists(st.integers(0, 3), max_size=3).map(tuple)),
    st.floats(allow_nan=True, allow_infinity=True).map(np.float64),
    st.text(max_size=12).map(np.str_),
    st.integers(-10**6, 10**6).map(np.int64),
    st.just(np.array([b"x"])),
)


@settings(max_examples=fuzz_examples(500), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(key=st.sampled_from(["delta", "dt", "clock"]), value=_ARRAYS, drop=st.booleans())
def test_mutated_feedforward_tables_are_refused_or_finite(tmp_path, key, value, drop):
    arrays = {"delta": np.zeros((5, 2)), "dt": np.float64(0.005), "clock": np.str_("trajectory")}
    if drop:
        arrays.pop(key)
    else:
        arrays[key] = value
    f = tmp_path / "mut.npz"
    np.savez(f, **arrays)
    try:
        pol = load_feedforward(str(f), 200.0, 2, SPAN)
    except ValueError as e:
        assert "mut.npz" in str(e), str(e)
        return
    assert pol.delta.ndim == 2 and pol.delta.shape[1] == 2 and np.all(np.isfinite(pol.delta))
    assert np.all(np.abs(pol.delta) <= SPAN) and pol.dt == 0.005


@pytest.mark.parametrize("hopping", [False, True])
def test_every_baseline_mode_is_a_policy_and_only_passthrough_hops(tmp_path, hopping):
    from ddpc_codegen.values.prefilter import PrefilterModel
    from ddpc_codegen.runtime.baselines import FeedforwardPolicy, PassthroughPolicy
    from ddpc_codegen.runtime.policy import Policy
    from firmware_bridge.baseline_modes import BASELINE_MODES, baseline_policy

    files = {"passthrough": None,
             "prefilter": str(PrefilterModel((1.0, 1.0), (0.0, 0.0), (3, 0), 0.005).save(tmp_path / "pf.json")),
             "feedforward": str(FeedforwardPolicy(np.zeros((4, 2))).save(tmp_path / "ff.npz"))}
    assert set(BASELINE_MODES) == set(files)
    for mode in BASELINE_MODES:
        if hopping and mode != "passthrough":
            with pytest.raises(ValueError, match=rf"^{mode} mode flies the flying scenario \(the hopping baselines "
                                                 r"run in-process\)$"):
                baseline_policy(mode, files[mode], 200.0, 2, hopping)
            continue
        pol, ahead = baseline_policy(mode, files[mode], 200.0, 2, hopping)
        assert isinstance(pol, Policy) and ahead.tolist() == (np.arange(pol.horizon) / 200.0).tolist()
    pt, ahead = baseline_policy("passthrough", None, 200.0, 3, hopping)
    assert isinstance(pt, PassthroughPolicy) and ahead.tolist() == [0.0]
    with pytest.raises(ValueError, match=r"^not a baseline mode: 'steer' \(one of \('passthrough', 'prefilter', "
                                         r"'feedforward'\)\)$"):
        baseline_policy("steer", None, 200.0, 2, False)
