"""The README and the docs site: the site builds with --strict, the generated reference pages follow
the code (every CLI flag, every config key and rule, every C function), the pages claim only what the
reports show, and the README stays one screen of real commands (the results pages: tests/docsgen)."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from ddpc_codegen.docsgen import results
from ddpc_codegen.docsgen.assets import MATHJAX_SCRIPT, mathjax_root
from ddpc_codegen.docsgen.c_api import TEMPLATES, c_api_page, declarations
from ddpc_codegen.docsgen.cli_reference import cli_page, flags_of, parser_of, parsers
from ddpc_codegen.docsgen.config_reference import attribute_docs, config_page, config_rules
from ddpc_codegen.docsgen.diagrams import steering_loop_svg

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


# ----------------------------------------------------------------------------- the site
@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site built once with mkdocs build --strict (the folder), or the build's output as the failure."""
    out = tmp_path_factory.mktemp("site") / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                       cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return out


def test_site_builds_with_strict(site):
    """mkdocs build --strict: a broken link, a missing nav page or a docstring warning fails."""
    for page in ("reference/cli", "reference/config", "reference/python-api", "reference/c-api", "results"):
        assert (site / page / "index.html").is_file(), page


# ----------------------------------------------------------------------------- CLI reference
def test_cli_page_lists_every_flag_of_every_parser():
    page = cli_page()
    seen = 0

    def walk(p, title):
        nonlocal seen
        for flag in flags_of(p):
            assert f"`{flag}`" in page, f"{title}: {flag} missing from the CLI reference"
            seen += 1
        for a in p._actions:
            for name, sub in (getattr(a, "choices", None) or {}).items() if hasattr(a, "add_parser") else ():
                assert f"`{title} {name}`" in page
                walk(sub, f"{title} {name}")

    for name, p in parsers().items():
        assert f"## {name}" in page
        walk(p, name)
    assert seen > 100  # the four commands have well over a hundred flags between them


def test_parser_of_captures_the_parser_main_builds():
    import argparse

    def main(argv):
        p = argparse.ArgumentParser(prog="probe")
        p.add_argument("--speed", type=float)
        p.parse_args(argv)
        raise AssertionError("nothing after parsing runs")

    assert flags_of(parser_of(main)) == ["--speed"]
    with pytest.raises(RuntimeError, match=r"^test_docs\._returns_early returned without parsing its arguments$"):
        parser_of(_returns_early)


def _returns_early(argv: list[str]) -> int:
    return 0


# ----------------------------------------------------------------------------- config reference
def test_config_page_lists_every_key_with_the_validators_rules():
    from ddpc_codegen.values.config import SteeringConfig
    from ddpc_codegen.errors import ConfigError

    rules = config_rules()
    page = config_page()
    for section, keys in rules.items():
        for key in keys:
            assert f"| `{key}` |" in page, (section, key)
    # the rule on the page is the validator's own message (checked independently here)
    with pytest.raises(ConfigError) as e:
        SteeringConfig.from_dict({"horizon": {"t_ini": 0, "t_f": 2}, "signals": {"inputs": ["u"], "outputs": ["y"]},
                                  "cost": {"Q": [1.0], "R": [1.0]}})
    rule = str(e.value).split("t_ini ", 1)[1].split(";")[0]
    assert rule in rules["horizon"]["t_ini"]["rules"]
    assert rules["horizon"]["t_ini"]["required"] and not rules["horizon"]["dt"]["required"]
    assert rules["cost"]["R_mode"]["default"] == "offset"
    for table in ("controller", "trajectory", "contact", "steering"):
        assert f"### `[{table}]`" in page


def test_attribute_docs_reads_grouped_and_continued_entries():
    class Example:
        """Example.

        Attributes:
            alpha: first line
                continued.
            kp, kd: gains [1/s^2], [1/s].

        Other text.
        """

    assert attribute_docs(Example) == {"alpha": "first line continued.", "kp": "gains [1/s^2], [1/s].",
                                       "kd": "gains [1/s^2], [1/s]."}
    assert attribute_docs(int) == {}


# ----------------------------------------------------------------------------- C API reference
def test_c_api_page_lists_every_function_of_the_header_templates():
    page = c_api_page()
    for template in ("solver.h.in", "artio.h.in", "adapt.h.in"):
        text = (TEMPLATES / template).read_text()
        names = set(re.findall(r"^\S.*?\{\{ name \}\}(_\w+)\(", text, re.M))
        assert names, template
        found = {n for kind, n, _ in declarations(template) if kind == "function"}
        assert found == {f"<name>{n}" for n in names}, template
        for n in names:
            assert f"`<name>{n}`" in page
    assert "{{" not in page and "{%" not in page


# ----------------------------------------------------------------------------- README
def test_readme_is_one_screen_and_opens_with_the_two_commands():
    lines = README.splitlines()
    assert len(lines) <= 150
    first_block = README.split("```bash\n", 1)[1].split("```", 1)[0].splitlines()
    assert README.index("```bash") < README.index("\n## ")  # before any section
    assert first_block[0].startswith("make demo")  # then the fast loop and the full one
    assert [w.split()[1] for w in first_block[1:3]] == ["check", "test"], first_block


def test_readme_has_the_results_markers_once():
    assert README.count(results.BEGIN) == 1 and README.count(results.END) == 1


def _commands(text: str) -> list[list[str]]:
    cmds = []
    for block in re.findall(r"```(?:bash|sh)\n(.*?)```", text, re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" #", 1)[0].strip()
            if line and not line.startswith("#"):
                cmds.append(shlex.split(line))
    return cmds


def test_readme_shell_blocks_name_only_existing_targets_and_commands():
    targets = set(re.findall(r"^([a-z][\w-]*):", (ROOT / "Makefile").read_text(), re.M))
    scripts = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"])
    cmds = _commands(README)
    assert len(cmds) >= 5
    for words in cmds:
        prog = Path(words[0]).name
        if prog == "make":
            assert words[1] in targets, words
        else:
            assert prog in scripts | {"pip"}, words
            if words[0].startswith(".venv/bin/"):
                assert prog in scripts
    for words in cmds:  # the subcommands named exist too
        if Path(words[0]).name == "ddpc-codegen":
            assert f"`ddpc-codegen {words[1]}`" in cli_page(), words


def _doc_pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def test_every_flag_in_a_documented_command_exists():
    """A `ddpc-*` command shown in the README or the docs uses only flags its parser has."""
    all_parsers = parsers()
    checked = 0
    for page in _doc_pages():
        for words in _commands(page.read_text()):
            prog = Path(words[0]).name
            if prog not in all_parsers:
                continue
            p = all_parsers[prog]
            if prog == "ddpc-codegen":
                p = next(a.choices[words[1]] for a in p._actions if hasattr(a, "add_parser"))
            for w in words[1:]:
                flag = w.split("=", 1)[0]
                if flag.startswith("--"):
                    assert flag in flags_of(p), f"{page.relative_to(ROOT)}: {prog} has no flag {flag}"
                    checked += 1
    assert checked > 20


def test_no_development_history_in_the_docs():
    for page in _doc_pages():
        text = page.read_text().lower()
        for phrase in ("this session", "the run before", "the helper", "previous release", "earlier run"):
            assert phrase not in text, f"{page.relative_to(ROOT)}: {phrase!r}"


def test_the_architecture_page_names_what_the_code_has():
    """docs/architecture.md: every package of ddpc_codegen is in the layer table, every test marker in the tier
    table, and every module it names (the companion loop's parts, the backend's files) exists."""
    page = (ROOT / "docs" / "architecture.md").read_text()
    packages = sorted(p.name for p in (ROOT / "ddpc_codegen").iterdir() if (p / "__init__.py").is_file())
    assert [p for p in packages if f"`{p}/`" not in page] == []
    markers = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["markers"]
    assert [m for m in (m.split(":")[0] for m in markers) if f"`{m}`" not in page] == []
    loop = page[page.index("## The companion loop"):page.index("## Import rules")]
    assert [f for f in re.findall(r"`(\w+\.py)`", loop) if not (ROOT / "firmware_bridge" / f).is_file()] == []
    assert "`firmware_bridge.Bridge`" in loop
    named = re.findall(r"`((?:\w+/)+\w+\.py)`", page)
    assert named and [f for f in named if not (ROOT / "ddpc_codegen" / f).is_file()
                      and not (ROOT / f).is_file()] == []


def _names_code(dotted: str) -> bool:
    """``a.b.c``: the longest prefix that is a module of the project, and the next name (if any) in its source."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        base = ROOT.joinpath(*parts[:i])
        source = base.with_suffix(".py") if base.with_suffix(".py").is_file() else base / "__init__.py"
        if source.is_file():
            return i == len(parts) or re.search(rf"\b{parts[i]}\b", source.read_text()) is not None
    return False


def test_every_module_the_docs_name_exists():
    """A path (``design/problem.py``), a file name (``bridge.py``) or a dotted name (``ddpc_codegen.runtime.policy``)
    of the project's code, written in the README or a docs page, names a module that exists: a moved module
    fails here until the page follows it."""
    files = {p.relative_to(ROOT).as_posix() for pkg in ("ddpc_codegen", "firmware_bridge", "tests", "examples")
             for p in (ROOT / pkg).rglob("*.py")}
    names = {f.rsplit("/", 1)[-1] for f in files}
    missing = []
    for page in _doc_pages():
        text = page.read_text()
        for f in re.findall(r"(?<![\w/.])((?:[\w-]+/)+[\w-]+\.py)\b", text):
            if not any(f == k or k.endswith("/" + f) for k in files):
                missing.append(f"{page.relative_to(ROOT)}: {f}")
        missing += [f"{page.relative_to(ROOT)}: {f}" for f in re.findall(r"(?<![\w/.-])([a-z_0-9]+\.py)\b", text)
                    if f not in names]
        missing += [f"{page.relative_to(ROOT)}: {d}" for d in
                    re.findall(r"\b((?:ddpc_codegen|firmware_bridge)(?:\.\w+)+)", text) if not _names_code(d)]
    assert missing == []


def _sitl_best(cond: dict, metric: str) -> tuple[str, float]:
    """The closest method of one SITL condition on one metric (None = not flown there)."""
    scores = {k: v for k, v in cond[metric].items() if v is not None}
    return min(scores.items(), key=lambda kv: kv[1])


def test_the_baselines_page_claims_only_what_the_sitl_report_shows():
    """docs/concepts/baselines.md states orderings, not figures: each one is read back from reports/sitl.json,
    so a re-measured report that changes an ordering fails here until the page is changed too."""
    sitl = json.loads((ROOT / "reports" / "sitl.json").read_text())
    flown = {ap: {c: v for c, v in rep["conditions"].items() if "skipped" not in v} for ap, rep in sitl.items()
             if ap in ("px4", "ardupilot")}
    for ap, conds in flown.items():  # on the estimate: the steering is closest everywhere
        for c, cond in conds.items():
            assert _sitl_best(cond, "rmse_z")[0] == "steered", (ap, c)
    for c, cond in flown["ardupilot"].items():  # true height: the same, except ILC on the repeated ellipse
        assert _sitl_best(cond, "rmse_z_truth")[0] == ("ilc" if c == "ellipse" else "steered"), c
    for c, cond in flown["px4"].items():  # PX4 true height: the estimator's error dominates
        assert cond["estimator_rms"]["steered"] > cond["rmse_z"]["steered"], c
        assert (_sitl_best(cond, "rmse_z_truth")[0] == "steered") == (c == "ellipse"), c
    page = (ROOT / "docs" / "concepts" / "baselines.md").read_text()
    assert "do not show that steering beats the best simple method" in page


def test_the_simulator_baselines_claims_match_the_summary():
    """The simulator half of baselines.md: steering closest off the repeated path, ILC on it (flying)."""
    base = json.loads((ROOT / "reports" / "summary.json").read_text())["baselines"]

    def best(scenario: str, cond: str) -> str:
        metric = base[scenario]["metric"]
        scores = {k: v[metric] for k, v in base[scenario]["conditions"][cond].items()
                  if isinstance(v, dict) and metric in v}
        return min(scores, key=scores.get)

    flying = base["flying"]["conditions"]
    assert best("flying", "ellipse (periodic)") == best("flying", "sensor noise") == "ilc"
    for cond in ("random smooth path", "push", "mass -300 g"):
        assert best("flying", cond) == "ddpc", cond
    assert flying["random smooth path"]["ilc"]["rmse_z"] > flying["random smooth path"]["passthrough"]["rmse_z"]
    for cond in base["hopping"]["conditions"]:
        assert best("hopping", cond) == "ddpc", cond


def test_the_reference_steering_page_claims_match_the_demo():
    """reference-steering.md: flying height error and hopping apex error down by more than an order of
    magnitude, the pitch error a little (reports/summary.json, make demo)."""
    s = json.loads((ROOT / "reports" / "summary.json").read_text())
    fly, hop = s["flying"], s["hopping"]
    assert fly["baseline"]["rmse_z"] > 10 * fly["steered"]["rmse_z"]
    assert fly["baseline"]["rmse_pitch"] > fly["steered"]["rmse_pitch"] > fly["baseline"]["rmse_pitch"] / 2
    assert hop["baseline"]["apex_error_mean_abs"] > 10 * hop["steered"]["apex_error_mean_abs"]
    page = " ".join((ROOT / "docs" / "concepts" / "reference-steering.md").read_text().split())
    assert "the height error drops by more than an order of magnitude, the pitch error a little" in page
    assert "the mean apex error drops by more than an order of magnitude" in page


def test_concept_pages_render_math_and_the_steering_loop_offline(site):
    """The built site serves MathJax itself (no CDN), the concept pages carry arithmatex math, and the
    steering-loop diagram is drawn by the build (an SVG, the same bytes twice)."""
    assert (site / MATHJAX_SCRIPT).stat().st_size > 100_000
    page = (site / "concepts" / "reference-steering" / "index.html").read_text()
    assert 'class="arithmatex"' in page and "steering-loop.svg" in page
    for html in site.rglob("*.html"):
        assert not re.search(r"<script[^>]+src=\"https?://", html.read_text()), html
    svg = (site / "figures" / "steering-loop.svg").read_text()
    assert svg.startswith("<?xml") and "<svg" in svg and svg == steering_loop_svg()


def test_every_formula_of_the_site_renders(site):
    """Each arithmatex formula typesets with the MathJax the site serves (in node): no TeX error, no
    undefined macro. Skipped without node."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("needs node to run MathJax")
    script = ROOT / "ddpc_codegen" / "docsgen" / "typeset_check.js"
    r = subprocess.run([node, str(script), str(mathjax_root()), str(site)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert int(re.search(r"(\d+) formulas", r.stdout).group(1)) >= 20, r.stdout  # the concept pages' were found
