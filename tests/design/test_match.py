"""Config against dataset (issue 12): names, order, units and dt are checked before the fit;
a mapping is explicit (--map-channels); every mismatch says how to fix it."""

import numpy as np
import pytest

from support.lti import random_lti
from ddpc_codegen import ConfigError, IODataset, SteeringConfig
from ddpc_codegen.pipeline.solver_build import build_from_config
from ddpc_codegen.cli.main import main
from ddpc_codegen.design.match import conform_dataset, parse_channel_map

TOML = """
name = "m"
[horizon]
t_ini = 4
t_f = 3
dt = 0.01
[signals]
inputs = ["z_ref", "pitch_ref"]
outputs = ["z", "pitch"]
input_units = ["m", "rad"]
output_units = ["m", "rad"]
[cost]
Q = [1.0, 1.0]
R = [0.1, 0.1]
[predictor]
method = "lsq"
"""


@pytest.fixture(scope="module")
def uy():
    sys_ = random_lti(3, 2, 2, 8)
    rng = np.random.default_rng(8)
    u = rng.standard_normal((300, 2))
    y, _ = sys_.simulate(u, rng.standard_normal(3))
    return u, y


def _cfg(tmp_path, text=TOML):
    f = tmp_path / "m.toml"
    f.write_text(text)
    return SteeringConfig.from_toml(f)


def _ds(uy, tmp_path, inputs=("z_ref", "pitch_ref"), outputs=("z", "pitch"), iu=("m", "rad"), ou=("m", "rad"),
        dt=0.01, extra=False, swap=False):
    u, y = uy
    if swap:  # the same recording with the input columns stored the other way round
        u = u[:, ::-1]
    if extra:  # one more input channel the config does not use
        u = np.hstack([u, np.ones((u.shape[0], 1))])
    ds = IODataset(u, y, dt, input_names=inputs, output_names=outputs, input_units=iu, output_units=ou)
    return ds, ds.save(tmp_path / "d.npz")


def _error(cfg, path, mapping=None):
    with pytest.raises(ConfigError) as e:
        build_from_config(cfg, path, channel_map=mapping)
    msg = str(e.value)
    assert str(path) in msg and "m.toml" in msg
    return msg


def test_matching_dataset_builds(uy, tmp_path):
    cfg = _cfg(tmp_path)
    _, path = _ds(uy, tmp_path)
    prob = build_from_config(cfg, path)
    assert prob.predictor.input_names == ("z_ref", "pitch_ref")


def test_swapped_channels_are_an_error_with_the_flag_to_confirm(uy, tmp_path):
    cfg = _cfg(tmp_path)
    _, path = _ds(uy, tmp_path, inputs=("pitch_ref", "z_ref"), iu=("rad", "m"), swap=True)
    msg = _error(cfg, path)
    assert "the dataset's inputs are ['pitch_ref', 'z_ref'] but the config lists ['z_ref', 'pitch_ref']" in msg
    assert "--map-channels z_ref=z_ref,pitch_ref=pitch_ref" in msg
    # Confirmed: the dataset's columns are reordered to the config's order.
    prob = build_from_config(cfg, path, channel_map=parse_channel_map("z_ref=z_ref,pitch_ref=pitch_ref"))
    ref = build_from_config(cfg, _ds(uy, tmp_path)[1])
    np.testing.assert_allclose(prob.predictor.Gy_u, ref.predictor.Gy_u, atol=1e-12)


def test_renamed_channels_need_a_mapping(uy, tmp_path):
    cfg = _cfg(tmp_path)
    _, path = _ds(uy, tmp_path, outputs=("pos_z", "att_pitch"))
    msg = _error(cfg, path)
    assert "the config's outputs ['z', 'pitch'] are not all in the dataset, whose outputs are ['pos_z', 'att_pitch']" in msg
    assert "--map-channels z=pos_z,pitch=att_pitch" in msg
    prob = build_from_config(cfg, path, channel_map={"z": "pos_z", "pitch": "att_pitch"})
    assert prob.predictor.output_names == ("z", "pitch")


def test_extra_dataset_channels_need_a_mapping(uy, tmp_path):
    cfg = _cfg(tmp_path)
    _, path = _ds(uy, tmp_path, inputs=("z_ref", "pitch_ref", "roll_ref"), iu=("m", "rad", "rad"), extra=True)
    assert "other order or a subset" in _error(cfg, path)
    build_from_config(cfg, path, channel_map={"z_ref": "z_ref"})


def test_units_and_dt_mismatch(uy, tmp_path):
    cfg = _cfg(tmp_path)
    _, path = _ds(uy, tmp_path, ou=("mm", "rad"))
    msg = _error(cfg, path)
    assert "output 'z' is in 'm' in the config but dataset channel 'z' is in 'mm'" in msg
    assert "convert the data to 'm' or set [signals] output_units" in msg
    _, path = _ds(uy, tmp_path, dt=0.005)
    msg = _error(cfg, path)
    assert "sampled every 0.005 s but [horizon] dt = 0.01 s; resample the data" in msg
    _, path = _ds(uy, tmp_path, ou=("", ""))  # unknown units in the data are not a mismatch
    build_from_config(cfg, path)


@pytest.mark.parametrize("text, fragment", [
    ("z", "'z' is not CONFIG_NAME=DATASET_NAME"),
    ("z=a,z=b", "'z' is mapped twice"),
    ("z=a,pitch=a", "two config channels map to the same dataset channel"),
])
def test_bad_map_syntax(text, fragment):
    with pytest.raises(ConfigError, match="--map-channels") as e:
        parse_channel_map(text)
    assert fragment in str(e.value)


def test_unknown_mapped_name(uy, tmp_path):
    cfg = _cfg(tmp_path)
    ds, _ = _ds(uy, tmp_path)
    with pytest.raises(ConfigError, match=r"--map-channels names \['height'\], which are not config channels"):
        conform_dataset(cfg, ds, {"height": "z"})


def test_cli_reports_mismatch_and_bad_flags(uy, tmp_path, capsys):
    _cfg(tmp_path)  # writes m.toml
    _, path = _ds(uy, tmp_path, outputs=("pos_z", "att_pitch"))
    out = tmp_path / "gen"
    assert main(["codegen", str(tmp_path / "m.toml"), "--dataset", str(path), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "ddpc-codegen codegen: error:" in err and "--map-channels z=pos_z,pitch=att_pitch" in err
    assert main(["codegen", str(tmp_path / "m.toml"), "--dataset", str(path), "--map-channels", "z"]) == 2
    assert "'z' is not CONFIG_NAME=DATASET_NAME" in capsys.readouterr().err
    # A second config that cannot load is refused before the first one is fitted.
    (tmp_path / "bad.toml").write_text(TOML.replace('[data]', '').replace('name = "m"', 'name = "m"\n[data]\ndataset = 5'))
    assert main(["codegen", str(tmp_path / "m.toml"), str(tmp_path / "bad.toml"), "--dataset", str(path),
                 "--map-channels", "z=pos_z,pitch=att_pitch", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "[data] dataset must be a path string; got 5" in err and "fitted" not in err
    assert not out.exists()
    with pytest.raises(SystemExit):
        main(["codegen", str(tmp_path / "m.toml"), "--backend", "cvx"])
    assert "invalid choice: 'cvx'" in capsys.readouterr().err
