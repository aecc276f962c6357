"""Config against dataset: channel names and order, units and sample time must agree before a fit.

A dataset recorded with other channel names (a log's topic fields, another robot) is used only
through an explicit mapping ``config name -> dataset name`` (``--map-channels z=pos_z,...`` on the
command line); everything else that differs is an error that says how to fix it.
"""

from __future__ import annotations

from typing import Mapping

from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.errors import ConfigError

__all__ = ["conform_dataset", "parse_channel_map", "DT_RTOL"]

# Relative tolerance on the sample time: float round-off of a stored dt, not a different rate.
DT_RTOL = 1e-9


def parse_channel_map(text: str | None) -> dict[str, str]:
    """``"cfg=data,cfg2=data2"`` -> {"cfg": "data", ...}; ConfigError naming the bad item."""
    if not text:
        return {}
    out: dict[str, str] = {}
    for item in text.split(","):
        cfg_name, sep, data_name = (s.strip() for s in item.partition("="))
        if not sep or not cfg_name or not data_name:
            raise ConfigError(f"--map-channels: {item.strip()!r} is not CONFIG_NAME=DATASET_NAME "
                              "(e.g. --map-channels z=pos_z,pitch=att_pitch)")
        if cfg_name in out:
            raise ConfigError(f"--map-channels: {cfg_name!r} is mapped twice")
        out[cfg_name] = data_name
    if len(set(out.values())) != len(out):
        raise ConfigError(f"--map-channels: two config channels map to the same dataset channel: {out}")
    return out


def _flag(mapping: Mapping[str, str]) -> str:
    return "--map-channels " + ",".join(f"{k}={v}" for k, v in mapping.items())


def _pick(kind: str, wanted: tuple[str, ...], have: tuple[str, ...], mapping: Mapping[str, str],
          where: str) -> list[int]:
    """Dataset column index of each config channel (mapped names first); ConfigError with a fix otherwise."""
    names = [mapping.get(n, n) for n in wanted]
    missing = [n for n in names if n not in have]
    if missing:
        hint = _flag({c: h for c, h in zip(wanted, have)}) if len(have) == len(wanted) else "--map-channels ..."
        raise ConfigError(
            f"{where}: the config's {kind} {list(wanted)} are not all in the dataset, whose {kind} are "
            f"{list(have)} (missing {missing}). Rename [signals] {kind} to the dataset's names, or map them "
            f"explicitly if that is intended, e.g. {hint}")
    idx = [have.index(n) for n in names]
    if not mapping and idx != list(range(len(have))):
        raise ConfigError(
            f"{where}: the dataset's {kind} are {list(have)} but the config lists {list(wanted)} "
            f"(other order or a subset). Reorder [signals] {kind}, or confirm the mapping with "
            f"{_flag({n: n for n in wanted})}")
    return idx


def _check_units(kind: str, cfg_names: tuple[str, ...], cfg_units: tuple[str, ...], data_names: list[str],
                 data_units: list[str], where: str) -> None:
    if not cfg_units:
        return
    for c, cu, d, du in zip(cfg_names, cfg_units, data_names, data_units):
        if du and cu and du.strip() != cu.strip():
            raise ConfigError(
                f"{where}: {kind[:-1]} {c!r} is in {cu!r} in the config but dataset channel {d!r} is in {du!r}; "
                f"convert the data to {cu!r} or set [signals] {kind[:-1]}_units to {du!r}")


def conform_dataset(config: SteeringConfig, dataset: IODataset, mapping: Mapping[str, str] | None = None,
                    where: str = "") -> IODataset:
    """The dataset with the config's channels, in the config's order and names, after checking
    names, order, units (where both sides state one) and dt.

    Args:
        mapping: config channel name -> dataset channel name, for the channels that differ
            (an explicit mapping also allows another order and extra dataset channels).
        where: what to name in messages (default: the config file and the dataset file).
    Raises:
        ConfigError saying how to fix it (rename, reorder, map, convert units, resample).
    """
    mapping = dict(mapping or {})
    where = where or config.source
    unknown = [k for k in mapping if k not in config.input_names + config.output_names]
    if unknown:
        raise ConfigError(f"{where}: --map-channels names {unknown}, which are not config channels "
                          f"(inputs {list(config.input_names)}, outputs {list(config.output_names)})")
    if abs(dataset.dt - config.dt) > DT_RTOL * config.dt:
        raise ConfigError(f"{where}: the dataset is sampled every {dataset.dt:g} s but [horizon] dt = {config.dt:g} s; "
                          "resample the data (e.g. ddpc-codegen import-ulog --rate) or fix [horizon] dt")
    cfg_in = config.input_names or tuple(dataset.input_names[: config.m])
    cfg_out = config.output_names or tuple(dataset.output_names[: config.p])
    iu = _pick("inputs", cfg_in, dataset.input_names, mapping, where)
    iy = _pick("outputs", cfg_out, dataset.output_names, mapping, where)
    if len(set(iu)) != len(iu) or len(set(iy)) != len(iy):
        raise ConfigError(f"{where}: two config channels read the same dataset channel after --map-channels "
                          f"{mapping}; map each config channel to its own dataset channel")
    _check_units("inputs", cfg_in, config.input_units, [dataset.input_names[i] for i in iu],
                 [dataset.input_units[i] for i in iu], where)
    _check_units("outputs", cfg_out, config.output_units, [dataset.output_names[i] for i in iy],
                 [dataset.output_units[i] for i in iy], where)
    if iu == list(range(dataset.m)) and iy == list(range(dataset.p)) and not mapping:
        return dataset
    return IODataset(
        [u[:, iu] for u in dataset.u], [y[:, iy] for y in dataset.y], dataset.dt,
        input_names=cfg_in, output_names=cfg_out,
        input_units=[dataset.input_units[i] for i in iu], output_units=[dataset.output_units[i] for i in iy],
        phases=None if dataset.phases is None else list(dataset.phases),
        metadata={**dataset.metadata, "channel_map": mapping},
    )
