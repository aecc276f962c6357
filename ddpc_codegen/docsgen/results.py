"""Render the measured results into the docs: the pages under ``docs/results/`` and the README's table.

Each measuring make target (``make demo``, ``make bench``, ``make bridge-demo``, ``make sitl-demo``, ``make
sitl-adapt``, ``make adapt-eval``) ends with ``python -m ddpc_codegen.docsgen.results``, which rewrites every results page from
whichever of ``reports/summary.json``, ``reports/bench.json`` and ``reports/sitl.json`` exist, copies the demo's
figures to ``docs/figures/`` and replaces the README's table between its marker comments. A report that does
not exist yet is named on its page with the target that writes it; nothing is copied by hand.

The pages: ``index.md`` (one short table per campaign, steered / best simple fix named), ``simulator.md``,
``bench.md``, ``sitl.md`` (a section per autopilot), ``adaptation.md`` and ``proxy.md``; each campaign's module renders its
page and its headline table (``results_sim``, ``results_bench``, ``results_sitl``, ``results_adapt``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from ddpc_codegen.docsgen import results_bench, results_bridge, results_proxy, results_proxy_soak, results_sim, results_sitl
from ddpc_codegen.docsgen.results_adapt import adaptation_page
from ddpc_codegen.docsgen.results_format import label, missing, page_head

ROOT = Path(__file__).resolve().parents[2]
BEGIN = "<!-- results:begin (written by make demo: python -m ddpc_codegen.docsgen.results) -->"
END = "<!-- results:end -->"
# report file -> the make target that writes it
REPORTS = {"summary.json": "make demo", "bench.json": "make bench", "sitl.json": "make sitl-demo",
           "proxy.json": "make proxy-demo", "proxy_soak.json": "make proxy-soak", "bridge.json": "make bridge-demo"}
PAGES = ("index.md", "simulator.md", "bench.md", "sitl.md", "adaptation.md", "proxy.md")  # under docs/results/

__all__ = ["ROOT", "BEGIN", "END", "REPORTS", "PAGES", "load_reports", "index_page", "pages", "readme_block",
           "replace_block", "copy_figures", "write_pages", "main"]


def load_reports(reports: Path) -> dict[str, dict]:
    """The reports that exist in ``reports`` (file name -> parsed JSON); unreadable JSON is an error."""
    out = {}
    for name in REPORTS:
        path = reports / name
        if path.is_file():
            try:
                out[name] = json.loads(path.read_text())
            except json.JSONDecodeError as e:
                raise ValueError(f"{path}: not valid JSON ({e}); rerun {REPORTS[name]}") from None
    return out


def _sitl_headlines(sitl: dict | None) -> list[str]:
    if sitl is None:
        return ["## Real autopilots (`make sitl-demo`)\n", missing("make sitl-demo", "sitl.json")]
    aps = results_sitl.autopilots(sitl)
    if not aps:
        return ["## Real autopilots (`make sitl-demo`)\n", "`make sitl-demo` found no SITL.\n"]
    out = []
    for name, ap in aps.items():
        out += [f"## {label(name)} SITL (`make sitl-demo`)\n",
                f"True-height RMSE per condition; details on the [SITL page](sitl.md#{label(name).lower()}).\n",
                results_sitl.headline(name, ap)]
    return out


def _proxy_headlines(proxy: dict | None) -> list[str]:
    head = "## Your own app through ddpc-proxy (`make proxy-demo`)\n"
    if proxy is None:
        return [head, missing("make proxy-demo", "proxy.json")]
    out = [head, "True-height RMSE of a plain pymavlink app with its own feed-forward, alone and steered through the "
           "proxy; details on the [proxy page](proxy.md).\n"]
    for name, ap in results_proxy.autopilots(proxy).items():
        out += [f"**{label(name)}**\n", results_proxy.headline(name, ap)]
    return out


def _soak_headline(soak: dict | None) -> list[str]:
    head = "## ddpc-proxy in a long session and under a flood (`make proxy-soak`)\n"
    if soak is None:
        return [head, missing("make proxy-soak", "proxy_soak.json")]
    return [head, "Messages lost or reordered and the latency the proxy adds: the [proxy page](proxy.md).\n"]


def index_page(reports: dict[str, dict]) -> str:
    """The headline page: one short table per campaign (simulator, bench, each autopilot)."""
    summary, bench = reports.get("summary.json"), reports.get("bench.json")
    out = [page_head("Results", "Every figure on these pages is rendered from `reports/*.json` by the make target "
                     "that measured it. The figure that judges the steering is **steered / best simple fix**: the "
                     "steered error over the lowest error of the controller's own feed-forward, a prefilter fitted "
                     "on the same data and ILC, on the same path (< 1: the steering is better; on the autopilots, "
                     "the true height). What the methods are: [reference steering](../concepts/reference-steering.md) "
                     "and [the simple fixes](../concepts/baselines.md).")]
    out += ["## Simulator (`make demo`)\n", "The judged error per scenario and condition; details on the "
            "[simulator page](simulator.md).\n", results_sim.headline(summary) if summary else
            missing("make demo", "summary.json")]
    out += ["## Solver timing (`make bench`)\n", "The generated solver's call per tick; details on the "
            "[bench page](bench.md).\n", results_bench.headline(bench) if bench else missing("make bench", "bench.json")]
    out += results_bridge.index_lines(reports.get("bridge.json"))
    out += _sitl_headlines(reports.get("sitl.json"))
    out += _proxy_headlines(reports.get("proxy.json"))
    out += _soak_headline(reports.get("proxy_soak.json"))
    out += ["## Online adaptation (`make adapt-eval`, `make sitl-adapt`)\n",
            "Static against adapted steering after a change mid-flight: the [adaptation page](adaptation.md).\n"]
    return "\n".join(out)


def pages(reports: dict[str, dict]) -> dict[str, str]:
    """Every results page (name under ``docs/results/`` -> Markdown) from the loaded reports (any subset)."""
    summary, sitl = reports.get("summary.json"), reports.get("sitl.json")
    return {"index.md": index_page(reports), "simulator.md": results_sim.sim_page(summary),
            "bench.md": results_bench.bench_page(reports.get("bench.json")) + "\n"
            + results_bridge.bridge_section(reports.get("bridge.json")), "sitl.md": results_sitl.sitl_page(sitl),
            "adaptation.md": adaptation_page(summary, sitl), "proxy.md": results_proxy.proxy_page(reports.get("proxy.json")) + "\n"
            + results_proxy_soak.soak_section(reports.get("proxy_soak.json"))}


def readme_block(reports: dict[str, dict]) -> str:
    """The README's results table (the simulator's headline table), marker comments included."""
    if "summary.json" not in reports:
        body = missing("make demo", "summary.json")
    else:
        s = reports["summary.json"]
        meta = s.get("meta", {})
        body = (results_sim.headline(s) + f"\nUnder a {meta.get('mass_error_kg', '?')} kg controller mass error, "
                + ("the interpreted QP" if meta.get("interpreted") else "the generated C solver")
                + " in the loop.\n")
    return f"{BEGIN}\n{body.rstrip()}\n{END}"


def replace_block(text: str, block: str) -> str:
    """``text`` with the part between the results markers (inclusive) replaced by ``block``."""
    i, j = text.find(BEGIN), text.find(END)
    if i < 0 or j < i:
        raise ValueError(f"no results markers in the text: expected {BEGIN!r} ... {END!r}")
    return text[:i] + block + text[j + len(END):]


def copy_figures(summary: dict, root: Path, dest: Path) -> list[Path]:
    """Copy the figures ``make demo`` listed in its summary into ``dest`` (the docs' figures)."""
    dest.mkdir(parents=True, exist_ok=True)
    copied = []
    for f in summary.get("meta", {}).get("figures", []):
        src = Path(f) if Path(f).is_absolute() else root / f
        if src.is_file():
            copied.append(Path(shutil.copy2(src, dest / src.name)))
    return copied


def write_pages(reports: dict[str, dict], docs: Path) -> list[Path]:
    """Write every results page into ``docs/results/``; returns their paths."""
    out = docs / "results"
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in pages(reports).items():
        (out / name).write_text(text)
        written.append(out / name)
    return written


def main(argv: list[str] | None = None) -> int:
    """Rewrite the results pages (``docs/results/``) and the README's results table from ``reports/``."""
    ap = argparse.ArgumentParser(prog="python -m ddpc_codegen.docsgen.results", description=main.__doc__)
    ap.add_argument("--reports", default=str(ROOT / "reports"), help="folder of the JSON reports")
    ap.add_argument("--docs", default=str(ROOT / "docs"), help="docs folder (results/, figures/)")
    ap.add_argument("--readme", default=str(ROOT / "README.md"), help="README with the results markers")
    a = ap.parse_args(argv)
    readme = Path(a.readme)
    try:
        reports = load_reports(Path(a.reports))
        if "summary.json" in reports:  # the README's table is make demo's: other targets leave it alone
            readme.write_text(replace_block(readme.read_text(), readme_block(reports)))
    except ValueError as e:
        print(f"docsgen: error: {e}", file=sys.stderr)
        return 2
    if "summary.json" in reports:
        copy_figures(reports["summary.json"], ROOT, Path(a.docs) / "figures")
    write_pages(reports, Path(a.docs))
    print(f"rendered {', '.join(reports) or 'no reports'} into {Path(a.docs) / 'results'}"
          + (f" and {readme}" if "summary.json" in reports else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
