from pathlib import Path

import numpy as np
import pytest

from ddpc_codegen import ConfigError, SteeringConfig

ROOT = Path(__file__).resolve().parents[2]

BASE = """
name = "t"
[horizon]
t_ini = 4
t_f = 3
[signals]
inputs = ["a", "b"]
outputs = ["c"]
[cost]
Q = [1.0]
R = [0.1, 0.2]
"""


def _load(tmp_path, text):
    f = tmp_path / "c.toml"
    f.write_text(text)
    return SteeringConfig.from_toml(f)


def test_shipped_flying_config_loads():
    cfg = SteeringConfig.from_toml(ROOT / "configs" / "flying.toml")
    assert (cfg.t_ini, cfg.t_f, cfg.m, cfg.p) == (20, 15, 2, 2)
    assert cfg.R_mode == "offset" and cfg.codegen["backend"] == "daqp"
    assert cfg.Q.shape == (2, 2) and cfg.Q[0, 0] == 1000.0
    assert cfg.dataset.endswith("data/flying.npz") and Path(cfg.dataset).is_absolute()


def test_minimal_config_defaults(tmp_path):
    cfg = _load(tmp_path, BASE)
    assert cfg.m == 2 and cfg.p == 1 and cfg.R_mode == "offset"
    assert np.all(np.isinf(cfg.u_min)) and np.all(np.isinf(cfg.du_max))
    assert cfg.predictor["method"] == "pem"


def test_rate_penalty_defaults_to_zero_and_enters_the_digest_only_when_used(tmp_path):
    a = _load(tmp_path, BASE)
    assert np.array_equal(a.R_du, np.zeros((2, 2))) and "R_du" not in a.to_dict()
    b = _load(tmp_path, BASE.replace("Q = [1.0]", "Q = [1.0]\nR_du = [0.0, 0.0]"))
    c = _load(tmp_path, BASE.replace("Q = [1.0]", "Q = [1.0]\nR_du = [0.5, 0.0]"))
    assert a.digest == b.digest != c.digest
    assert c.to_dict()["R_du"] == [[0.5, 0.0], [0.0, 0.0]]
    d = _load(tmp_path, BASE.replace("Q = [1.0]", "Q = [1.0]\nR_ddu = [0.0, 2.0]"))
    assert np.array_equal(a.R_ddu, np.zeros((2, 2))) and "R_ddu" not in a.to_dict()
    assert d.to_dict()["R_ddu"] == [[0.0, 0.0], [0.0, 2.0]] and d.digest not in (a.digest, c.digest)
    with pytest.raises(ConfigError, match=r"\[cost\] R_ddu needs t_ini >= 2 .* t_ini is 1"):
        _load(tmp_path, BASE.replace("Q = [1.0]", "Q = [1.0]\nR_ddu = [1.0, 1.0]").replace("t_ini = 4", "t_ini = 1"))
    # R_de pairs input i with output i: this config has 2 inputs and 1 output
    with pytest.raises(ConfigError, match=r"\[cost\] R_de pairs input i with output i and needs m <= p; m is 2, p is 1"):
        _load(tmp_path, BASE.replace("Q = [1.0]", "Q = [1.0]\nR_de = [1.0, 0.0]"))
    e = _load(tmp_path, BASE.replace("Q = [1.0]", "Q = [1.0]\nR_de = [0.0, 0.0]"))
    assert np.array_equal(e.R_de, np.zeros((2, 2))) and e.digest == a.digest and "R_de" not in e.to_dict()
    f = _load(tmp_path, BASE.replace("Q = [1.0]", "Q = [1.0]\nR_doffset = [3.0, 0.0]"))
    assert f.to_dict()["R_doffset"] == [[3.0, 0.0], [0.0, 0.0]] and f.digest not in (a.digest, c.digest, d.digest)
    assert "R_doffset" not in a.to_dict() and np.array_equal(a.R_doffset, np.zeros((2, 2)))
    # the changes of u - u_nom: u_nom is a parameter only in R_mode "offset"
    with pytest.raises(ConfigError, match=r"\[cost\] R_doffset penalizes the changes of u - u_nom and needs "
                                          r"R_mode = \"offset\" .* R_mode is 'increment'"):
        _load(tmp_path, BASE.replace("Q = [1.0]", 'Q = [1.0]\nR_mode = "increment"\nR_doffset = [1.0, 0.0]'))


def test_artificial_io_table_reaches_the_hopping_setup(tmp_path):
    from ddpc_codegen.design.hopping_data import ArtificialIOSpec

    cfg = _load(tmp_path, BASE + "\n[artificial_io]\nt_a = 24\nmin_ascent = 6\nnoise_level_online = 0.002\n"
                "refit_residual = 0.004\n")
    spec = ArtificialIOSpec(**cfg.artificial_io)
    assert (spec.t_a, spec.min_ascent, spec.noise_level_online, spec.refit_residual) == (24, 6, 0.002, 0.004)
    assert ArtificialIOSpec().refit_residual == 0.0  # off unless configured
    with pytest.raises(ConfigError, match=r"\[artificial_io\] refit_residual must be a number >= 0"):
        _load(tmp_path, BASE + "\n[artificial_io]\nrefit_residual = -1e-3\n")
    assert spec.t_d == ArtificialIOSpec().t_d  # unset keys keep their defaults
    assert _load(tmp_path, BASE).digest != cfg.digest


def test_full_matrix_weight(tmp_path):
    cfg = _load(tmp_path, BASE.replace("R = [0.1, 0.2]", "R = [[1.0, 0.1], [0.1, 2.0]]"))
    assert cfg.R[0, 1] == 0.1


def test_digest_ignores_codegen_but_not_weights(tmp_path):
    a = _load(tmp_path, BASE)
    b = _load(tmp_path, BASE + '\n[codegen]\nbackend = "osqp"\n')
    c = _load(tmp_path, BASE.replace("Q = [1.0]", "Q = [2.0]"))
    assert a.digest == b.digest != c.digest


@pytest.mark.parametrize(
    "edit, message",
    [
        (("Q = [1.0]", "Q = [1.0, 2.0]"), "[cost] Q must have 1 entries"),
        (("R = [0.1, 0.2]", "R = [0.1, -0.2]"), "[cost] R diagonal entries must be finite and >= 0"),
        (("t_f = 3", "t_f = 0"), "t_f must be a positive integer; got 0"),
        (("t_f = 3", "t_f = 2.5"), "t_f must be a positive integer; got 2.5"),
        (("t_ini = 4\n", ""), "[horizon] t_ini is required but missing"),
        (("Q = [1.0]", 'Q = [1.0]\nR_mode = "abs"'), "R_mode must be one of ['absolute', 'offset', 'increment']; got 'abs'"),
        (("Q = [1.0]", "Q = [1.0]\nlamda_sigma = 3"), "[cost] lamda_sigma is not a known key"),
        (("[cost]", "[bounds]\nu_min = [1, 0]\nu_max = [0, 1]\n[cost]"), "channel 0: lower 1.0 >= upper 0.0"),
        (("[cost]", "[bounds]\ndu_max = [0, 1]\n[cost]"), "du_max must be > 0"),
        (("[cost]", "[bounds]\nu_min = [1, 0, 2]\n[cost]"), "u_min must have 2 entries (one per channel); got 3"),
        (('name = "t"', 'name = "t"\n[codegen]\nbackend = "cvx"'), "[codegen] backend must be one of ['daqp', 'osqp']; got 'cvx'"),
        (('name = "t"', 'name = "t"\n[predictor]\nmethod = "dmd"'), "[predictor] method must be one of ['pem', 'lsq']; got 'dmd'"),
        (('outputs = ["c"]', "outputs = []"), "[signals] outputs must be a non-empty list"),
        (("[cost]", "[costs]"), "'costs' is not a known top-level key"),
        (("Q = [1.0]", "Q = [1.0]\nR_du = [1.0]"), "[cost] R_du must have 2 entries"),
        (("Q = [1.0]", "Q = [1.0]\nR_ddu = [1.0, -1.0]"), "[cost] R_ddu"),
        (("Q = [1.0]", "Q = [1.0]\nR_de = [1.0, -1.0]"), "[cost] R_de"),
        (("Q = [1.0]", "Q = [1.0]\nR_doffset = [1.0]"), "[cost] R_doffset must have 2 entries"),
        (('name = "t"', 'name = "t"\n[artificial_io]\nt_a = 0'), "[artificial_io] t_a must be an integer >= 1; got 0"),
        (('name = "t"', 'name = "t"\n[artificial_io]\nmin_ascent = 2.5'), "[artificial_io] min_ascent must be an integer >= 1; got 2.5"),
        (('name = "t"', 'name = "t"\n[artificial_io]\nnoise_level = -1e-3'), "[artificial_io] noise_level must be a number >= 0"),
        (('name = "t"', 'name = "t"\n[artificial_io]\nt_dd = 3'), "[artificial_io] t_dd is not a known key"),
    ],
)
def test_bad_config_messages_name_key_and_value(tmp_path, edit, message):
    with pytest.raises(ConfigError) as e:
        _load(tmp_path, BASE.replace(*edit))
    assert message in str(e.value)
    assert "c.toml" in str(e.value)


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        SteeringConfig.from_toml(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        _load(tmp_path, "name = ")


def test_nonsymmetric_and_indefinite_weights():
    kw = dict(t_ini=2, t_f=2, m=1, p=2, R=[1.0])
    with pytest.raises(ConfigError, match="symmetric"):
        SteeringConfig(Q=[[1, 2], [0, 1]], **kw)
    with pytest.raises(ConfigError, match="positive semidefinite"):
        SteeringConfig(Q=[[1, 2], [2, 1]], **kw)


def test_denoise_online_must_be_a_boolean(tmp_path):
    import tomllib

    raw = tomllib.loads((Path(__file__).resolve().parents[2] / "configs" / "hopping.toml").read_text())
    assert raw["artificial_io"]["denoise_online"] is True
    raw["artificial_io"]["denoise_online"] = 1
    with pytest.raises(ConfigError, match=r"\[artificial_io\] denoise_online.*true or false"):
        SteeringConfig.from_dict(raw, source="h.toml")


def test_max_output_noise_is_validated_per_output(tmp_path):
    cfg = _load(tmp_path, BASE + "[data]\nmax_output_noise = [5e-4]\n")
    assert cfg.max_output_noise.tolist() == [5e-4]
    assert _load(tmp_path, BASE).max_output_noise is None
    with pytest.raises(ConfigError, match=r"\[data\] max_output_noise must have 1 entries"):
        _load(tmp_path, BASE + "[data]\nmax_output_noise = [5e-4, 1e-3]\n")
    with pytest.raises(ConfigError, match=r"\[data\] max_output_noise must be >= 0"):
        _load(tmp_path, BASE + "[data]\nmax_output_noise = -1.0\n")


@pytest.mark.parametrize("horizon, m, message", [
    ({"t_ini": 20, "t_f": 5000}, 2, "[horizon] t_f must be at most 2000 steps; got 5000"),
    ({"t_ini": 2001, "t_f": 5}, 2, "[horizon] t_ini must be at most 2000 steps; got 2001"),
    ({"t_ini": 1001, "t_f": 1000}, 2, "[horizon] t_ini/t_f give a Hankel of (m+p)*(t_ini+t_f) = 8004 rows, more than "
     "8000; shorten the horizons (move blocking keeps long previews cheap)"),
    ({"t_ini": 10, "t_f": 10}, 33, "[signals] inputs must have at most 32 channels; got 33"),
])
def test_size_limits_before_any_matrix(horizon, m, message):
    raw = {"horizon": horizon, "signals": {"inputs": [f"u{i}" for i in range(m)], "outputs": ["y0", "y1"]},
           "cost": {"Q": [1.0, 1.0], "R": [1.0] * m}}
    with pytest.raises(ConfigError) as e:
        SteeringConfig.from_dict(raw, source="c.toml")
    assert str(e.value) == f"c.toml: {message}"
