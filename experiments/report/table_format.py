"""A rendered table (GitHub Markdown, LaTeX booktabs) and the mean ± std cells every table uses."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np


def mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (ddof=1; NaN for a single value: one seed has no spread)."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0:
        return math.nan, math.nan
    return float(arr.mean()), float(arr.std(ddof=1)) if arr.size > 1 else math.nan


@dataclass
class Table:
    """A rendered table: header, rows of cells, and which cells are best (bold)."""

    title: str
    header: list[str]
    rows: list[list[str]]
    bold: set[tuple[int, int]]
    note: str = ""

    def markdown(self) -> str:
        """GitHub Markdown."""
        def cell(r: int, c: int, text: str) -> str:
            return f"**{text}**" if (r, c) in self.bold else text

        lines = [f"### {self.title}", ""]
        lines.append("| " + " | ".join(self.header) + " |")
        lines.append("|" + "|".join(["---"] + [":-:"] * (len(self.header) - 1)) + "|")
        for r, row in enumerate(self.rows):
            lines.append("| " + " | ".join(cell(r, c, t) for c, t in enumerate(row)) + " |")
        if self.note:
            lines += ["", self.note]
        return "\n".join(lines) + "\n"

    def latex(self) -> str:
        """A booktabs tabular inside a table environment."""
        def esc(text: str) -> str:
            text = text.replace("\\", r"\textbackslash{}")
            for ch in "_%&#$":
                text = text.replace(ch, "\\" + ch)
            return text.replace("±", r"$\pm$").replace("↑", r"$\uparrow$").replace("↓", r"$\downarrow$")

        def cell(r: int, c: int, text: str) -> str:
            return rf"\textbf{{{esc(text)}}}" if (r, c) in self.bold else esc(text)

        cols = "l" + "c" * (len(self.header) - 1)
        lines = [r"\begin{table}[t]", r"\centering", rf"\caption{{{esc(self.title)}}}"]
        lines += [r"\resizebox{\linewidth}{!}{%", rf"\begin{{tabular}}{{{cols}}}", r"\toprule"]
        lines.append(" & ".join(esc(h) for h in self.header) + r" \\")
        lines.append(r"\midrule")
        for r, row in enumerate(self.rows):
            lines.append(" & ".join(cell(r, c, t) for c, t in enumerate(row)) + r" \\")
        lines += [r"\bottomrule", r"\end{tabular}}", r"\end{table}"]
        return "\n".join(lines) + "\n"


def plus_minus(mean: float, std: float, scale: float = 100.0, digits: int = 1) -> str:
    if math.isnan(mean):
        return "–"
    if math.isnan(std):  # a single value: no ± to show
        return f"{mean * scale:.{digits}f}"
    return f"{mean * scale:.{digits}f} ± {std * scale:.{digits}f}"


def machine_kind(hw: dict[str, Any] | None) -> str | None:
    """``<CPU model> (<vector width>)`` from a run's ``hardware`` record (``experiments.run.job.hardware``); None where it names no CPU."""
    if not hw or not hw.get("cpu_model"):
        return None
    return f"{hw['cpu_model']} ({hw.get('torch_cpu_capability') or '?'})"

