"""The [adapt] section of a steering config: validated with the key and the value named, defaults in one place."""

from __future__ import annotations

import pytest

from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.errors import ConfigError
from ddpc_codegen.values.adapt import AdaptSettings


def _raw(adapt) -> dict:
    raw = {"horizon": {"t_ini": 3, "t_f": 4}, "signals": {"inputs": ["a"], "outputs": ["b"]},
           "cost": {"Q": [1.0], "R": [1.0]}}
    if adapt is not None:
        raw["adapt"] = adapt
    return raw


def test_adapt_section_values_and_defaults():
    assert SteeringConfig.from_dict(_raw(None)).adapt == AdaptSettings()
    cfg = SteeringConfig.from_dict(_raw({"enabled": True, "forgetting": 0.99, "period_ticks": 50, "dither": 0.01,
                                         "max_change": 0.1, "window": 80}), "c.toml")
    assert cfg.adapt == AdaptSettings(enabled=True, forgetting=0.99, period_ticks=50, dither=0.01, max_change=0.1,
                                      window=80)
    assert cfg.to_dict()["adapt"]["forgetting"] == 0.99
    # what may update a solver in flight does not change the problem it solves
    assert cfg.digest == SteeringConfig.from_dict(_raw(None), "c.toml").digest
    assert "adapt" not in SteeringConfig.from_dict(_raw({"forgetting": 0.9})).to_dict()  # disabled: not recorded


@pytest.mark.parametrize("adapt, message", [
    (3, r"^c.toml: \[adapt\] must be a table; got 3$"),
    ({"windw": 3}, r"^c.toml: \[adapt\] windw is not a known key; allowed: \['enabled', 'forgetting', "
                   r"'period_ticks', 'dither', 'max_change', 'window', 'min_excitation', "
                   r"'min_improvement', 'max_gain_change', 'offset', 'max_offset'\]$"),
    ({"forgetting": 1.5}, r"^c.toml: \[adapt\] forgetting must be in \(0, 1\]; got 1.5$"),
    ({"max_change": 0}, r"^c.toml: \[adapt\] max_change must be > 0; got 0$"),
    ({"period_ticks": True}, r"^c.toml: \[adapt\] period_ticks must be an integer >= 1; got True$"),
    ({"enabled": 1}, r"^c.toml: \[adapt\] enabled must be true or false; got 1$"),
])
def test_adapt_section_errors_name_the_key_and_the_value(adapt, message):
    with pytest.raises(ConfigError, match=message):
        SteeringConfig.from_dict(_raw(adapt), "c.toml")
