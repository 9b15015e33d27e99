"""The paper's own figures (Yan et al., NeurIPS 2025), transcribed from its LaTeX tables.

Each :class:`PaperTable` keeps the ``\\label`` and caption of the table it came from, its columns
and its rows' cells as printed (``"74.9 ± 6.9"``; ``"/"`` where the paper prints a slash, i.e. no
figure). Row and column names are the paper's (``\\methodname`` written RDD, citations dropped).
``tests/experiments/test_paper_figures.py`` checks every cell against the LaTeX source
($RDD_PAPER_TEX). Where the paper reports two averages for one experiment, the main-text table
averages over the tasks where its policy succeeds and the appendix table (``-add``) over all 18.
"""

from __future__ import annotations

import re
from dataclasses import dataclass


@dataclass(frozen=True)
class PaperTable:
    """One table of the paper: its label, caption, column names and each row's cells."""

    label: str
    caption: str
    columns: tuple[str, ...]
    rows: dict[str, tuple[str, ...]]

    def cell(self, row: str, column: str) -> str | None:
        """The printed cell, or None where the paper has no such row, column or figure."""
        if row not in self.rows or column not in self.columns:
            return None
        text = self.rows[row][self.columns.index(column)]
        return None if text == "/" else text

    def mean(self, row: str, column: str) -> float | None:
        """The cell's leading number (the mean of ``mean ± std``), or None."""
        text = self.cell(row, column)
        number = re.match(r"-?\d+(\.\d+)?", text or "")
        return float(number.group()) if number else None


def _table(label: str, caption: str, columns: tuple[str, ...], rows: dict[str, str]) -> PaperTable:
    cells = {name: tuple(c.strip() for c in text.split(" | ")) for name, text in rows.items()}
    for name, row in cells.items():
        if len(row) != len(columns):
            raise ValueError(f"{label}, row {name!r}: {len(row)} cells for {len(columns)} columns")
    return PaperTable(label, caption, columns, cells)


# Our evaluation tasks -> the paper's column names (its abbreviations of RLBench's task names).
TASKS = {
    "open_drawer": "Open Drawer",
    "put_item_in_drawer": "Put in Drawer",
    "stack_blocks": "Stack Blocks",
    "meat_off_grill": "Meat off Grill",
    "push_buttons": "Push Buttons",
    "turn_tap": "Turn Tap",
    "place_shape_in_shape_sorter": "Sort Shape",
}

SUMMARY = ("Avg. Succ.", "Avg. Rank")
# The 13 tasks of the main-text tables (the paper leaves out those where its policy fails).
MAIN_TASKS = (
    "Close Jar", "Install Bulb", "Meat off Grill", "Open Drawer", "Place Wine", "Push Buttons",
    "Put in Cupboard", "Put in Drawer", "Put in Safe", "Drag Stick", "Slide Block",
    "Sweep to Dustpan", "Turn Tap",
)
# The appendix's 18 tasks, in its column order.
ALL_TASKS = (
    "Close Jar", "Insert Peg", "Install Bulb", "Meat off Grill", "Open Drawer", "Place Cups",
    "Sort Shape", "Place Wine", "Push Buttons", "Put in Cupboard", "Put in Drawer", "Put in Safe",
    "Drag Stick", "Slide Block", "Stack Blocks", "Stack Cups", "Sweep to Dustpan", "Turn Tap",
)
# The necessity table's 11: MAIN_TASKS less those its planner was finetuned on beforehand.
NECESSITY_TASKS = MAIN_TASKS[2:]

_TABLES = (
    _table(
        "tab-main",
        "Multi-task success rates (%) on RLBench.",
        (*SUMMARY, *MAIN_TASKS),
        {
            "w/o Finetune": (
                "52.6 ± 8.2 | 4.5 ± 1.2 | 27.6 ± 26.4 | 34.8 ± 14.2 | 46.4 ± 26.8 | "
                "95.6 ± 6.1 | 83.2 ± 13.0 | 54.8 ± 9.1 | 41.2 ± 20.1 | 36.4 ± 28.8 | "
                "58.8 ± 23.3 | 36.0 ± 21.8 | 57.2 ± 14.9 | 22.8 ± 32.5 | 89.2 ± 13.4"
            ),
            "Uniform": (
                "71.3 ± 5.4 | 3.1 ± 1.2 | 46.4 ± 29.9 | 51.2 ± 19.2 | 76.4 ± 22.4 | "
                "100.0 ± 0.0 | 80.8 ± 14.5 | 82.0 ± 7.8 | 36.8 ± 15.4 | 98.0 ± 2.7 | "
                "92.4 ± 10.8 | 64.8 ± 16.7 | 64.4 ± 9.9 | 34.8 ± 37.7 | 98.8 ± 3.6"
            ),
            "UVD": (
                "71.4 ± 5.1 | 3.0 ± 1.3 | 44.0 ± 28.7 | 54.8 ± 20.0 | 85.2 ± 20.6 | "
                "100.0 ± 0.0 | 80.8 ± 15.3 | 67.2 ± 13.6 | 35.2 ± 12.1 | 90.4 ± 8.6 | "
                "96.8 ± 6.6 | 74.4 ± 29.2 | 66.8 ± 21.2 | 43.6 ± 24.6 | 89.6 ± 11.1"
            ),
            "RDD (Ours)": (
                "74.9 ± 6.9 | 2.2 ± 0.9 | 46.0 ± 28.2 | 52.8 ± 16.4 | 84.4 ± 21.1 | "
                "99.2 ± 2.4 | 86.4 ± 15.4 | 84.0 ± 7.8 | 41.2 ± 17.1 | 97.2 ± 3.1 | "
                "98.4 ± 3.2 | 68.0 ± 25.0 | 65.2 ± 14.3 | 57.2 ± 29.7 | 94.0 ± 5.1"
            ),
            "Expert": (
                "75.1 ± 4.7 | 2.2 ± 1.0 | 50.4 ± 33.1 | 50.4 ± 13.3 | 94.4 ± 9.7 | "
                "99.2 ± 2.4 | 81.6 ± 15.0 | 85.6 ± 6.0 | 39.6 ± 15.6 | 91.2 ± 7.3 | "
                "97.6 ± 5.1 | 75.2 ± 24.6 | 66.4 ± 22.0 | 48.8 ± 35.5 | 96.0 ± 5.7"
            ),
        },
    ),
    _table(
        "tab-main-add",
        "Main results with all RLBench Tasks.",
        (*SUMMARY, *ALL_TASKS),
        {
            "w/o Finetune": (
                "39.7 ± 6.5 | 4.3 ± 1.3 | 27.6 ± 26.4 | 5.6 ± 6.7 | 34.8 ± 14.2 | "
                "46.4 ± 26.8 | 95.6 ± 6.1 | 3.2 ± 4.3 | 16.0 ± 11.7 | 83.2 ± 13.0 | "
                "54.8 ± 9.1 | 41.2 ± 20.1 | 36.4 ± 28.8 | 58.8 ± 23.3 | 36.0 ± 21.8 | "
                "57.2 ± 14.9 | 2.8 ± 2.6 | 2.8 ± 3.6 | 22.8 ± 32.5 | 89.2 ± 13.4"
            ),
            "Uniform": (
                "54.5 ± 4.1 | 3.1 ± 1.2 | 46.4 ± 29.9 | 8.8 ± 11.8 | 51.2 ± 19.2 | "
                "76.4 ± 22.4 | 100.0 ± 0.0 | 0.8 ± 1.6 | 25.6 ± 9.2 | 80.8 ± 14.5 | "
                "82.0 ± 7.8 | 36.8 ± 15.4 | 98.0 ± 2.7 | 92.4 ± 10.8 | 64.8 ± 16.7 | "
                "64.4 ± 9.9 | 13.6 ± 7.8 | 5.2 ± 4.7 | 34.8 ± 37.7 | 98.8 ± 3.6"
            ),
            "UVD": (
                "54.3 ± 3.9 | 3.2 ± 1.2 | 44.0 ± 28.7 | 10.4 ± 14.1 | 54.8 ± 20.0 | "
                "85.2 ± 20.6 | 100.0 ± 0.0 | 1.2 ± 1.8 | 25.2 ± 11.0 | 80.8 ± 15.3 | "
                "67.2 ± 13.6 | 35.2 ± 12.1 | 90.4 ± 8.6 | 96.8 ± 6.6 | 74.4 ± 29.2 | "
                "66.8 ± 21.2 | 9.6 ± 6.2 | 1.6 ± 3.7 | 43.6 ± 24.6 | 89.6 ± 11.1"
            ),
            "Expert": (
                "57.6 ± 3.3 | 2.0 ± 0.9 | 50.4 ± 33.1 | 12.0 ± 17.9 | 50.4 ± 13.3 | "
                "94.4 ± 9.7 | 99.2 ± 2.4 | 3.2 ± 3.9 | 26.0 ± 10.6 | 81.6 ± 15.0 | "
                "85.6 ± 6.0 | 39.6 ± 15.6 | 91.2 ± 7.3 | 97.6 ± 5.1 | 75.2 ± 24.6 | "
                "66.4 ± 22.0 | 14.8 ± 11.2 | 5.2 ± 4.4 | 48.8 ± 35.5 | 96.0 ± 5.7"
            ),
            "RDD (Ours)": (
                "57.3 ± 5.3 | 2.4 ± 1.1 | 46.0 ± 28.2 | 16.8 ± 18.6 | 52.8 ± 16.4 | "
                "84.4 ± 21.1 | 99.2 ± 2.4 | 2.0 ± 2.0 | 32.4 ± 10.2 | 86.4 ± 15.4 | "
                "84.0 ± 7.8 | 41.2 ± 17.1 | 97.2 ± 3.1 | 98.4 ± 3.2 | 68.0 ± 25.0 | "
                "65.2 ± 14.3 | 5.2 ± 3.6 | 1.6 ± 2.7 | 57.2 ± 29.7 | 94.0 ± 5.1"
            ),
        },
    ),
    _table(
        "tab-abl-alpha",
        "Results when tuning the weighting parameter alpha.",
        SUMMARY,
        {
            "0": "75.0 ± 2.5 | 3.0 ± 1.0",
            "0.5": "75.7 ± 2.4 | 2.5 ± 0.7",
            "1": "81.1 ± 0.9 | 2.3 ± 1.4",
            "2": "76.2 ± 3.0 | 2.2 ± 0.8",
        },
    ),
    _table(
        "tab-abl-alpha-add",
        "Multi-task performance with different weighting parameter alpha.",
        (*SUMMARY, *ALL_TASKS),
        {
            "0": (
                "57.3 ± 2.1 | 2.8 ± 1.0 | 74.7 ± 10.0 | 0.0 ± 0.0 | 32.0 ± 18.2 | "
                "52.0 ± 14.2 | 98.7 ± 1.9 | 6.7 ± 5.0 | 29.3 ± 5.0 | 81.3 ± 5.0 | "
                "90.7 ± 5.0 | 62.7 ± 12.4 | 96.0 ± 5.7 | 77.3 ± 3.8 | 76.0 ± 11.8 | "
                "58.7 ± 9.4 | 18.7 ± 12.4 | 1.3 ± 1.9 | 78.7 ± 16.4 | 96.0 ± 3.3"
            ),
            "0.5": (
                "57.6 ± 2.2 | 2.7 ± 0.8 | 73.3 ± 10.5 | 0.0 ± 0.0 | 33.3 ± 11.5 | "
                "49.3 ± 21.0 | 100.0 ± 0.0 | 5.3 ± 3.8 | 29.3 ± 6.8 | 92.0 ± 5.7 | "
                "85.3 ± 6.8 | 62.7 ± 13.2 | 96.0 ± 3.3 | 80.0 ± 0.0 | 76.0 ± 14.2 | "
                "58.7 ± 6.8 | 17.3 ± 13.6 | 0.0 ± 0.0 | 80.0 ± 15.0 | 97.3 ± 1.9"
            ),
            "1": (
                "61.0 ± 0.4 | 2.3 ± 1.4 | 68.0 ± 17.3 | 4.0 ± 3.3 | 41.3 ± 21.7 | "
                "96.0 ± 5.7 | 100.0 ± 0.0 | 1.3 ± 1.9 | 32.0 ± 5.7 | 96.0 ± 3.3 | "
                "78.7 ± 8.2 | 57.3 ± 3.8 | 97.3 ± 1.9 | 97.3 ± 3.8 | 88.0 ± 8.6 | "
                "73.3 ± 3.8 | 4.0 ± 3.3 | 1.3 ± 1.9 | 66.7 ± 5.0 | 94.7 ± 5.0"
            ),
            "2": (
                "58.0 ± 2.3 | 2.2 ± 0.8 | 76.0 ± 9.8 | 0.0 ± 0.0 | 33.3 ± 10.5 | "
                "48.0 ± 11.3 | 100.0 ± 0.0 | 8.0 ± 3.3 | 29.3 ± 3.8 | 88.0 ± 6.5 | "
                "88.0 ± 8.6 | 60.0 ± 9.8 | 100.0 ± 0.0 | 81.3 ± 6.8 | 77.3 ± 12.4 | "
                "58.7 ± 6.8 | 14.7 ± 10.0 | 1.3 ± 1.9 | 84.0 ± 17.3 | 96.0 ± 5.7"
            ),
        },
    ),
    _table(
        "tab-abl-enc",
        "Results when using different visual encoders.",
        SUMMARY,
        {
            "LIV": "81.1 ± 0.9 | 3.7 ± 1.6",
            "R3M": "80.0 ± 3.5 | 3.9 ± 1.7",
            "VIP": "75.3 ± 3.4 | 4.1 ± 2.0",
            "VC-1": "75.5 ± 3.1 | 3.8 ± 2.2",
            "CLIP": "78.2 ± 2.1 | 4.7 ± 2.0",
            "DINOv2": "78.4 ± 2.4 | 4.5 ± 1.8",
            "ResNet": "81.1 ± 2.5 | 3.4 ± 1.5",
        },
    ),
    _table(
        "tab-abl-enc-add",
        "Multi-task performances with different visual representations.",
        (*SUMMARY, *ALL_TASKS),
        {
            "LIV": (
                "61.0 ± 0.4 | 3.6 ± 1.7 | 68.0 ± 17.3 | 4.0 ± 3.3 | 41.3 ± 21.7 | "
                "96.0 ± 5.7 | 100.0 ± 0.0 | 1.3 ± 1.9 | 32.0 ± 5.7 | 96.0 ± 3.3 | "
                "78.7 ± 8.2 | 57.3 ± 3.8 | 97.3 ± 1.9 | 97.3 ± 3.8 | 88.0 ± 8.6 | "
                "73.3 ± 3.8 | 4.0 ± 3.3 | 1.3 ± 1.9 | 66.7 ± 5.0 | 94.7 ± 5.0"
            ),
            "R3M": (
                "59.2 ± 2.5 | 4.2 ± 1.8 | 65.3 ± 21.0 | 4.0 ± 5.7 | 44.0 ± 13.1 | "
                "97.3 ± 3.8 | 98.7 ± 1.9 | 0.0 ± 0.0 | 12.0 ± 3.3 | 86.7 ± 6.8 | "
                "89.3 ± 5.0 | 50.7 ± 10.0 | 85.3 ± 5.0 | 94.7 ± 5.0 | 94.7 ± 5.0 | "
                "82.7 ± 12.4 | 8.0 ± 3.3 | 1.3 ± 1.9 | 53.3 ± 8.2 | 97.3 ± 3.8"
            ),
            "VIP": (
                "56.5 ± 2.0 | 4.0 ± 2.0 | 72.0 ± 14.2 | 2.7 ± 1.9 | 38.7 ± 15.4 | "
                "93.3 ± 9.4 | 100.0 ± 0.0 | 5.3 ± 5.0 | 22.7 ± 10.0 | 89.3 ± 8.2 | "
                "92.0 ± 3.3 | 64.0 ± 8.6 | 93.3 ± 3.8 | 89.3 ± 10.0 | 10.7 ± 7.5 | "
                "46.7 ± 36.7 | 2.7 ± 1.9 | 5.3 ± 3.8 | 92.0 ± 8.6 | 97.3 ± 1.9"
            ),
            "VC-1": (
                "56.9 ± 1.6 | 3.7 ± 2.3 | 73.3 ± 9.4 | 1.3 ± 1.9 | 30.7 ± 18.6 | "
                "93.3 ± 9.4 | 100.0 ± 0.0 | 8.0 ± 3.3 | 20.0 ± 8.6 | 86.7 ± 10.0 | "
                "93.3 ± 5.0 | 65.3 ± 8.2 | 93.3 ± 6.8 | 92.0 ± 8.6 | 9.3 ± 6.8 | "
                "52.0 ± 31.5 | 4.0 ± 3.3 | 9.3 ± 7.5 | 92.0 ± 8.6 | 100.0 ± 0.0"
            ),
            "CLIP": (
                "58.4 ± 1.6 | 4.3 ± 2.0 | 62.7 ± 21.7 | 4.0 ± 3.3 | 46.7 ± 15.4 | "
                "96.0 ± 5.7 | 100.0 ± 0.0 | 0.0 ± 0.0 | 16.0 ± 3.3 | 82.7 ± 13.6 | "
                "89.3 ± 5.0 | 46.7 ± 13.2 | 81.3 ± 3.8 | 94.7 ± 5.0 | 94.7 ± 5.0 | "
                "81.3 ± 10.5 | 10.7 ± 3.8 | 5.3 ± 5.0 | 52.0 ± 8.6 | 88.0 ± 14.2"
            ),
            "DINOv2": (
                "58.3 ± 1.4 | 4.4 ± 1.6 | 65.3 ± 18.0 | 2.7 ± 3.8 | 41.3 ± 21.2 | "
                "98.7 ± 1.9 | 100.0 ± 0.0 | 1.3 ± 1.9 | 13.3 ± 1.9 | 80.0 ± 8.6 | "
                "88.0 ± 3.3 | 50.7 ± 15.4 | 85.3 ± 5.0 | 94.7 ± 5.0 | 94.7 ± 5.0 | "
                "78.7 ± 6.8 | 9.3 ± 1.9 | 4.0 ± 3.3 | 46.7 ± 5.0 | 94.7 ± 7.5"
            ),
            "ResNet": (
                "60.5 ± 2.0 | 3.8 ± 1.7 | 68.0 ± 20.4 | 2.7 ± 3.8 | 46.7 ± 10.5 | "
                "96.0 ± 5.7 | 100.0 ± 0.0 | 0.0 ± 0.0 | 13.3 ± 5.0 | 84.0 ± 6.5 | "
                "93.3 ± 1.9 | 61.3 ± 9.4 | 98.7 ± 1.9 | 90.7 ± 8.2 | 86.7 ± 10.5 | "
                "73.3 ± 6.8 | 17.3 ± 11.5 | 1.3 ± 1.9 | 56.0 ± 5.7 | 100.0 ± 0.0"
            ),
        },
    ),
    _table(
        "tab-abl-ep",
        "Results with different numbers of demonstrations per task.",
        SUMMARY,
        {
            "1 (RDD)": "77.9 ± 4.5 | 2.0 ± 0.9",
            "3 (RDD)": "81.1 ± 0.9 | 1.6 ± 0.6",
            "3 (UVD)": "75.6 ± 1.8 | 2.4 ± 0.6",
        },
    ),
    _table(
        "tab-abl-ep-add",
        "Multi-task performance with different numbers of demonstrations.",
        (*SUMMARY, *ALL_TASKS),
        {
            "1 (RDD)": (
                "59.1 ± 3.4 | 1.8 ± 0.8 | 75.6 ± 11.1 | 6.2 ± 5.7 | 35.6 ± 9.5 | "
                "65.8 ± 20.9 | 100.0 ± 0.0 | 5.8 ± 4.7 | 25.8 ± 3.8 | 91.1 ± 7.7 | "
                "86.7 ± 5.7 | 60.4 ± 11.8 | 97.8 ± 2.0 | 78.2 ± 13.3 | 61.8 ± 28.7 | "
                "79.6 ± 16.2 | 11.6 ± 8.1 | 2.2 ± 2.7 | 87.1 ± 16.2 | 92.9 ± 14.7"
            ),
            "3 (RDD)": (
                "61.0 ± 0.4 | 1.8 ± 0.7 | 68.0 ± 17.3 | 4.0 ± 3.3 | 41.3 ± 21.7 | "
                "96.0 ± 5.7 | 100.0 ± 0.0 | 1.3 ± 1.9 | 32.0 ± 5.7 | 96.0 ± 3.3 | "
                "78.7 ± 8.2 | 57.3 ± 3.8 | 97.3 ± 1.9 | 97.3 ± 3.8 | 88.0 ± 8.6 | "
                "73.3 ± 3.8 | 4.0 ± 3.3 | 1.3 ± 1.9 | 66.7 ± 5.0 | 94.7 ± 5.0"
            ),
            "3 (UVD)": (
                "57.1 ± 0.3 | 2.3 ± 0.6 | 66.7 ± 13.2 | 4.0 ± 5.7 | 37.3 ± 19.1 | "
                "93.3 ± 9.4 | 100.0 ± 0.0 | 2.7 ± 1.9 | 21.3 ± 10.5 | 77.3 ± 11.5 | "
                "62.7 ± 12.4 | 44.0 ± 6.5 | 84.0 ± 6.5 | 96.0 ± 5.7 | 85.3 ± 13.2 | "
                "82.7 ± 12.4 | 16.0 ± 3.3 | 1.3 ± 1.9 | 60.0 ± 16.3 | 93.3 ± 5.0"
            ),
        },
    ),
    _table(
        "tab-abl-realworld-libero",
        "Performance on real-world and OOD sub-tasks (IoU).",
        ("AgiBot. (Real World)", "LIBERO (OOD)"),
        {
            "UVD": "0.506 | 0.598",
            "RDD": "0.706 | /",
            "RDD (beta=0.25)": "/ | 0.624",
            "RDD (beta=0.10)": "/ | 0.630",
            "RDD (beta=0.05)": "/ | 0.614",
        },
    ),
    _table(
        "tab-main-pretrain-planner",
        "Vanilla Planner without finetuning on the target task.",
        SUMMARY,
        {
            "w/o finetuning on target task": "77.9 ± 4.3 | 1.6 ± 0.5",
            "RDD (Ours)": "79.6 ± 7.2 | 1.4 ± 0.5",
        },
    ),
    _table(
        "tab-main-pretrain-planner-multi-task",
        "Multi-task performance of Vanilla Planner without finetuning on the target task.",
        (*SUMMARY, *NECESSITY_TASKS),
        {
            "w/o finetuning on target task": (
                "77.9 ± 4.3 | 1.6 ± 0.5 | 99.2 ± 2.4 | 99.6 ± 1.2 | 86.4 ± 8.8 | "
                "70.4 ± 8.0 | 61.2 ± 16.8 | 86.0 ± 14.3 | 94.8 ± 9.0 | 74.0 ± 23.3 | "
                "62.4 ± 16.8 | 30.0 ± 15.3 | 92.4 ± 14.4"
            ),
            "RDD (Ours)": (
                "79.6 ± 7.2 | 1.4 ± 0.5 | 84.4 ± 21.1 | 99.2 ± 2.4 | 86.4 ± 15.4 | "
                "84.0 ± 7.8 | 41.2 ± 17.1 | 97.2 ± 3.1 | 98.4 ± 3.2 | 68.0 ± 25.0 | "
                "65.2 ± 14.3 | 57.2 ± 29.7 | 94.0 ± 5.1"
            ),
        },
    ),
    _table(
        "tab-main-gemini",
        "Comparing RDD with Gemini-2.5-pro.",
        SUMMARY,
        {
            "Gemini-2.5-pro": "72.6 ± 4.7 | 1.7 ± 0.4",
            "RDD (Ours)": "74.9 ± 6.9 | 1.3 ± 0.4",
        },
    ),
    _table(
        "tab-main-gemini-multi-task",
        "Comparing RDD with Gemini-2.5-pro.",
        (*SUMMARY, *MAIN_TASKS),
        {
            "Gemini-2.5-pro": (
                "72.6 ± 4.7 | 1.7 ± 0.4 | 41.2 ± 30.1 | 40.8 ± 16.5 | 83.2 ± 15.2 | "
                "99.6 ± 1.2 | 86.4 ± 11.1 | 82.4 ± 8.6 | 38.4 ± 10.6 | 94.0 ± 6.8 | "
                "93.6 ± 9.2 | 73.6 ± 22.3 | 63.6 ± 14.4 | 48.4 ± 14.9 | 99.2 ± 2.4"
            ),
            "RDD (Ours)": (
                "74.9 ± 6.9 | 1.3 ± 0.4 | 46.0 ± 28.2 | 52.8 ± 16.4 | 84.4 ± 21.1 | "
                "99.2 ± 2.4 | 86.4 ± 15.4 | 84.0 ± 7.8 | 41.2 ± 17.1 | 97.2 ± 3.1 | "
                "98.4 ± 3.2 | 68.0 ± 25.0 | 65.2 ± 14.3 | 57.2 ± 29.7 | 94.0 ± 5.1"
            ),
        },
    ),
    _table(
        "tab-faiss_rdd",
        "Performance of FAISS nearest neighbor search and RDD time on NVIDIA 4090.",
        ("Dim", "Vec Num", "QPS", "L_max", "L_I", "RDD Time (s)"),
        {
            "NVIDIA 4090": (
                "2048 | 10M | 386 | 100 | 500 | "
                "115 (4.3 fps)"
            ),
        },
    ),)
PAPER_TABLES: dict[str, PaperTable] = {t.label: t for t in _TABLES}
