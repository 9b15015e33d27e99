"""rdd.progress: the one progress bar of the CLI and the harness, and its process-wide switch."""

from __future__ import annotations

import sys
from types import SimpleNamespace

from rdd import progress as bars


def test_switch_decides_for_every_bar(capsys):
    try:
        bars.show_progress(True)  # the harness: drawn even when stderr is not a terminal
        assert bars.progress_enabled()
        assert list(bars.progress(range(3), "counting")) == [0, 1, 2]
        assert "counting" in capsys.readouterr().err
        bars.show_progress(False)  # parallel sweep jobs
        assert not bars.progress_enabled()
        episodes = [SimpleNamespace(name="a", num_frames=4), SimpleNamespace(name="b", num_frames=2)]
        assert list(bars.track_episodes(episodes, "embedding")) == episodes
        assert list(bars.progress(range(2), "hidden", leave=True)) == [0, 1]
        err = capsys.readouterr().err
        assert "hidden" not in err and "embedding" not in err
    finally:
        bars.show_progress(None)
    assert bars.progress_enabled() == sys.stderr.isatty()  # the default: on a terminal only
