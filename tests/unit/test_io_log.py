"""Run logger and progress line."""

import io
import logging

from cfddem.io.log import Progress, setup_run_logger


def test_run_logger_writes_file_no_duplicates(tmp_path):
    lg = setup_run_logger(tmp_path)
    lg.info("first")
    lg = setup_run_logger(tmp_path)
    logging.getLogger("cfddem.gas").warning("second")
    for h in lg.handlers:
        h.flush()
    text = (tmp_path / "run.log").read_text()
    assert text.count("first") == 1 and text.count("second") == 1
    assert "WARNING" in text and "cfddem.gas" in text


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_progress_rate_limit_rates_and_eta():
    clock, s = Clock(), io.StringIO()
    pr = Progress(end_time=6.0, stream=s, interval=1.0, is_tty=True, clock=clock)
    assert not pr.update(0.0, 0, 0)           # starts the clocks
    clock.t = 0.5
    assert not pr.update(0.001, 10, 400)      # too soon
    clock.t = 2.0
    assert pr.update(0.002, 100, 1600)        # 1600 steps in 2 s; 0.001 s sim per wall s
    assert "800 steps/s" in pr.last_line and "100 particles" in pr.last_line
    # ETA = (6 - 0.002) / 0.001 s = 5998 s = 1:39:58
    assert "ETA 1:39:58" in pr.last_line
    assert s.getvalue().startswith("\r") and "\n" not in s.getvalue()
    pr.close()
    assert s.getvalue().endswith("\n")


def test_progress_plain_lines_when_not_tty():
    clock, s = Clock(), io.StringIO()
    pr = Progress(end_time=1.0, stream=s, line_interval=10.0, clock=clock)
    pr.update(0.0, 0, 0)
    for k in range(1, 31):
        clock.t = float(k)
        pr.update(k * 0.01, 5, 100 * k)
    assert pr.lines_written == 3 and s.getvalue().count("\n") == 3 and "\r" not in s.getvalue()
