"""The sweep's on-disk fit cache: a fitted Predictor as ``.npz`` (numbers only) + JSON, with a content hash.

No pickle: a cache folder is user-writable, and unpickling runs code. A file is read with
``allow_pickle=False``, each entry's declared size checked before it is read
(:func:`~ddpc_codegen.design.data.checked_entry`), and refused unless its content hash, its key and the
predictor's own digest (a hash of its matrices) all match.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from ddpc_codegen.design.data import checked_entry, checked_json_entry
from ddpc_codegen.design.hankel import PEReport
from ddpc_codegen.design.predictor import Predictor
from ddpc_codegen.errors import DataError

__all__ = ["save_predictor", "load_predictor", "FORMAT"]

FORMAT = "ddpc-sweep-fit"
_MATRICES = ("Gy_w", "Gy_u", "Gs_w", "Gs_u", "singular_values")


def _arrays(pred: Predictor) -> dict[str, np.ndarray]:
    out = {k: np.ascontiguousarray(getattr(pred, k), dtype=float) for k in _MATRICES}
    pe = pred.options.get("_pe_report")
    if pe is not None:
        out["pe_singular_values"] = np.ascontiguousarray(pe.singular_values, dtype=float)
    if pred.options.get("_r_factor") is not None:
        out["r_factor"] = np.ascontiguousarray(pred.options["_r_factor"], dtype=float)
    return out


def _content_hash(meta: dict, arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256(json.dumps(meta, sort_keys=True).encode())
    for k in sorted(arrays):
        h.update(k.encode() + str(arrays[k].shape).encode() + arrays[k].tobytes())
    return h.hexdigest()


def save_predictor(path: Path, pred: Predictor, key: str) -> Path:
    """Write ``pred`` under ``key`` (the cache key its file is named for); atomic (temporary file + rename)."""
    pe = pred.options.get("_pe_report")
    meta = {"format": FORMAT, "version": 1, "key": key, "digest": pred.digest,
            "fields": {"t_ini": pred.t_ini, "t_f": pred.t_f, "m": pred.m, "p": pred.p, "method": pred.method,
                       "rank": int(pred.rank), "n_columns": int(pred.n_columns), "dt": float(pred.dt),
                       "input_names": list(pred.input_names), "output_names": list(pred.output_names)},
            "options": {k: v for k, v in pred.options.items() if not k.startswith("_")},
            "pe": None if pe is None else {
                "order": pe.order, "rank": pe.rank, "required_rank": pe.required_rank, "tol": float(pe.tol),
                "condition_number": float(pe.condition_number), "columns": pe.columns,
                "near_constant_inputs": list(pe.near_constant_inputs),
                "near_constant_outputs": list(pe.near_constant_outputs),
                "channel_std": {k: float(v) for k, v in pe.channel_std.items()}}}
    arrays = _arrays(pred)
    meta["sha256"] = _content_hash(meta, arrays)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)
    tmp.replace(path)
    return path


def load_predictor(path: Path, key: str) -> Predictor:
    """The Predictor cached in ``path`` under ``key``; DataError when the file is damaged, edited or another's."""
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = checked_json_entry(z, "meta", path, "fit cache header")
            arrays = {k: checked_entry(z, k) for k in z.files if k != "meta"}
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise DataError("not a sweep fit cache file")
        stored = meta.pop("sha256", None)
        if stored != _content_hash(meta, arrays) or meta.get("key") != key:
            raise DataError("its content hash or key does not match (edited, damaged or another fit's file)")
        f, pe = meta["fields"], meta["pe"]
        opts = dict(meta["options"])
        if pe is not None:
            opts["_pe_report"] = PEReport(singular_values=arrays["pe_singular_values"],
                                          **{**pe, "near_constant_inputs": tuple(pe["near_constant_inputs"]),
                                             "near_constant_outputs": tuple(pe["near_constant_outputs"])})
        if "r_factor" in arrays:
            opts["_r_factor"] = arrays["r_factor"]
        pred = Predictor(**{**f, "input_names": tuple(f["input_names"]), "output_names": tuple(f["output_names"])},
                         **{k: arrays[k] for k in _MATRICES}, options=opts)
        if pred.digest != meta["digest"]:
            raise DataError("the predictor's matrices do not match its digest")
        return pred
    except DataError as e:
        raise DataError(f"sweep fit cache {path}: {e}; delete it to fit again") from e
    except (OSError, EOFError, ValueError, KeyError, TypeError, AttributeError, RecursionError, zipfile.BadZipFile,
            zlib.error) as e:
        raise DataError(f"sweep fit cache {path} is damaged ({type(e).__name__}: {e}); delete it to fit again") from e
