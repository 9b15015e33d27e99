"""The paper's figures in experiments.report.paper_figures against the paper's LaTeX source.

The source is read from $RDD_PAPER_TEX (never copied into the repository); without it the check
against the source is skipped and only the mapping onto our names is tested.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from experiments.report.paper_compare import SPECS
from experiments.report.paper_figures import PAPER_TABLES, TASKS

_NESTED = re.compile(r"\\begin\{tabular\}\[c\]\{@\{\}c@\{\}\}(.*?)\\end\{tabular\}", re.S)
_LEAD_COLUMNS = ("Method", "Visu. Repr.", "alpha", "Demo. Num.", "Hardware")


def _plain(text: str) -> str:
    """LaTeX cell -> the text the data module writes (macros dropped, ± kept)."""
    text = re.sub(r"\\text\{\\tiny\s*±\s*([\d.]+)\s*\}", r"± \1", text)
    text = re.sub(r"~?\\cite\{[^}]*\}", "", text)
    text = re.sub(r"\\text(?:bf|it)\{([^}]*)\}", r"\1", text)
    text = text.replace(r"\methodname{}", "RDD").replace(r"\methodname", "RDD")
    text = text.replace(r"$\oodtradeoffcoef=", "beta=").replace(r"$\tradeoffcoef$", "alpha")
    text = re.sub(r"\$\((?:\\uparrow|\\downarrow)\)\$", "", text)
    text = text.replace("$L_{max}$", "L_max").replace(r"$L_{\interval}$", "L_I")
    text = text.replace("$", "").replace("~", " ")
    return re.sub(r"\s+", " ", text).strip()


def parse_tables(tex: str) -> dict[str, dict[str, dict[str, str]]]:
    """``{label: {row: {column: cell}}}`` for every tabular environment with a ``\\label``."""
    out: dict[str, dict[str, dict[str, str]]] = {}
    for m in re.finditer(r"\\begin\{(table\*?|wraptable)\}(.*?)\\end\{\1\}", tex, re.S):
        label = re.search(r"\\label\{(tab-[^}]*)\}", m.group(2))
        body = re.search(r"\\begin\{tabular\}\{[^}]*\}(.*)\\end\{tabular\}", m.group(2), re.S)
        if not (label and body):
            continue
        flat = _NESTED.sub(lambda n: " " + n.group(1).replace("\\\\", " ") + " ", body.group(1))
        rules = r"\\(specialrule\{[^}]*\}\{[^}]*\}\{[^}]*\}|toprule|midrule|bottomrule)"
        flat = re.sub(rules, "", flat)
        rows: dict[str, dict[str, str]] = {}
        header: list[str] = []
        for line in flat.split("\\\\"):
            cells = [_plain(c) for c in line.split("&")]
            if not cells[0]:
                continue
            if cells[0] in _LEAD_COLUMNS:
                header = cells[1:]
                continue
            rows.setdefault(cells[0], {}).update(zip(header, cells[1:], strict=True))
        out[label.group(1)] = rows
    return out


@pytest.fixture(scope="module")
def paper_tables() -> dict[str, dict[str, dict[str, str]]]:
    path = os.environ.get("RDD_PAPER_TEX")
    if not path:
        pytest.skip("set RDD_PAPER_TEX to the paper's LaTeX source (rdd_paper.tex) to check "
                    "the transcribed figures")
    return parse_tables(Path(path).read_text())


@pytest.mark.parametrize("label", sorted(PAPER_TABLES))
def test_transcribed_figures_match_the_latex_source(paper_tables, label: str) -> None:
    table = PAPER_TABLES[label]
    ours = {row: dict(zip(table.columns, cells, strict=True)) for row, cells in table.rows.items()}
    assert ours == paper_tables[label]


def test_every_table_of_the_paper_is_transcribed(paper_tables) -> None:
    assert set(paper_tables) == set(PAPER_TABLES)


def test_every_mapping_names_a_transcribed_row_and_column() -> None:
    paper_tasks = set(TASKS.values())
    for spec in SPECS.values():
        for label in (spec.summary, spec.per_task):
            if label is None:
                continue
            table = PAPER_TABLES[label]
            assert set(spec.rows.values()) <= set(table.rows), (label, spec.rows)
        assert spec.avg_column in PAPER_TABLES[spec.summary].columns
    # the appendix's main table holds every task of ours
    assert paper_tasks <= set(PAPER_TABLES["tab-main-add"].columns)
