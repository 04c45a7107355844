"""Run logger and progress line."""

import io
import logging

from cfddem.io.log import Progress, log_repeat_totals, setup_run_logger


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


def _lines(path):
    return path.read_text().splitlines()


def test_repeated_warning_is_rate_limited_with_a_final_count(tmp_path, capsys):
    lg = setup_run_logger(tmp_path, stderr=True)
    child = logging.getLogger("cfddem.run")
    for k in range(1, 1235):
        child.warning("t = %.4f s: %d particle(s) left the domain", 0.001 * k, k % 7)
        if k % 100 == 0:
            lg.info("checkpoint %d", k)  # INFO repeats are not limited
    lg.warning("a warning that comes once")
    assert log_repeat_totals(lg) == [
        "warning repeated 1234 times in this run (4 logged), the last: t = 1.2340 s: 2 particle(s) left the domain"]
    for h in lg.handlers:
        h.flush()
    lines = _lines(tmp_path / "run.log")
    left = [ln for ln in lines if "left the domain" in ln]
    # occurrences 1, 10, 100 and 1000 logged, then the total: 5 lines out of 1234
    assert len(left) == 5
    assert left[0].endswith("t = 0.0010 s: 1 particle(s) left the domain")
    assert left[1].endswith("t = 0.0100 s: 3 particle(s) left the domain [10th time; repeats are counted, "
                            "the total is logged at the end of the run]")
    assert "t = 0.1000 s" in left[2] and "[100th time" in left[2]
    assert "t = 1.0000 s" in left[3] and "[1000th time" in left[3]
    assert "INFO" in left[4] and "1234 times" in left[4]
    assert sum("checkpoint" in ln for ln in lines) == 12
    assert sum("comes once" in ln for ln in lines) == 1
    assert not any("repeated" in ln and "comes once" in ln for ln in lines)
    # the console shows the same lines: a record reaching both handlers is counted once
    err = capsys.readouterr().err.splitlines()
    assert sum("left the domain" in ln for ln in err) == 5
    # a new run (same folder, a resume) counts afresh
    lg = setup_run_logger(tmp_path)
    child.warning("t = %.4f s: %d particle(s) left the domain", 2.0, 1)
    assert log_repeat_totals(lg) == []


def test_rate_limit_keys_on_the_template_and_the_logger(tmp_path):
    lg = setup_run_logger(tmp_path)
    for _ in range(3):
        logging.getLogger("cfddem.a").warning("same text")
        logging.getLogger("cfddem.b").warning("same text")
        lg.warning("100 % literal, no arguments")
    assert sorted(log_repeat_totals(lg)) == [
        "warning repeated 3 times in this run (1 logged), the last: 100 % literal, no arguments",
        "warning repeated 3 times in this run (1 logged), the last: same text",
        "warning repeated 3 times in this run (1 logged), the last: same text"]
    assert log_repeat_totals(logging.getLogger("not.a.run.logger")) == []


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
