"""Run logging for ``training.run``: metrics.csv rows, the progress display and TensorBoard events.

* ``format_row(metrics, fields)``: one metrics.csv row (lists as JSON, missing values empty);
  ``read_metrics(path)`` reads a metrics.csv back (numbers as floats, lists decoded).
* ``Progress``: one plain line per evaluation on stdout, and a progress bar on stderr (env steps,
  env steps/s, the latest new-skill success, ETA) when stderr is a terminal.
* ``TensorBoardLogger``: TensorBoard event files in the run directory (tensorboardX, a brax
  dependency). Scalars: every number of the metrics dict ``train``'s ``progress_fn`` gets, lists
  per element (``skill_steps/<skill>``, ``length_histogram/k<K>``, ...) and the average
  consecutive execution ``skill_avg_consecutive/<skill>``, all at step = env steps. A resumed run
  opens a new event file with ``purge_step`` = the checkpoint's env steps + 1: TensorBoard then
  hides the events of the earlier files at steps past the checkpoint (those a killed run logged
  after its last checkpoint and the resume computes again), exactly as metrics.csv is cut back.
  ``read_scalars(run_dir)`` reads them back with the same purge rule.
"""

from __future__ import annotations

import csv
import glob
import json
import math
import os
import struct
import sys
import threading
import time
from typing import Optional, Sequence

# ----------------------------------------------------------------------------- metrics.csv


def release_free_memory() -> bool:
    """Return the C heap's free memory to the operating system (glibc ``malloc_trim(0)``; False and
    nothing done elsewhere). XLA's compiler frees hundreds of MiB after compiling the training
    iteration, but glibc keeps freed memory in its arenas: a stack run measured 1,607 MiB resident
    at its first evaluation after a cold compile and 942 MiB after the trim (docs/research/scaling.md, "Stack
    memory"). ``training.run`` trims before each rss_mb reading, so rss_mb tracks live memory."""
    global _libc
    if _libc is None:
        try:
            import ctypes

            lib = ctypes.CDLL(None)
            _libc = lib if hasattr(lib, "malloc_trim") else False
        except (OSError, AttributeError):
            _libc = False
    if not _libc:
        return False
    _libc.malloc_trim(0)
    return True


_libc = None


def resident_mb() -> float:
    """This process's resident set size now, in MiB (metrics.csv ``rss_mb``, written at each
    evaluation): /proc/self/statm on Linux; elsewhere the peak RSS (``ru_maxrss``)."""
    try:
        with open("/proc/self/statm") as f:
            pages = int(f.read().split()[1])
        return round(pages * os.sysconf("SC_PAGE_SIZE") / 2**20, 1)
    except (OSError, ValueError, IndexError):
        import resource

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux, bytes on macOS
        return round(peak / (2**20 if sys.platform == "darwin" else 2**10), 1)


def format_row(metrics: dict, fields: Sequence[str]) -> list:
    """A metrics.csv row: lists as JSON, missing values as empty strings."""
    return [json.dumps(metrics[k]) if isinstance(metrics.get(k), list) else metrics.get(k, "") for k in fields]


def _parse_cell(text: str):
    if text == "":
        return None
    if text.startswith("["):
        return json.loads(text)
    try:
        return float(text)
    except ValueError:
        return text


def read_metrics(path: str) -> list[dict]:
    """The rows of a metrics.csv as dicts: numbers as floats, JSON lists decoded, empty cells None."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return [{k: _parse_cell(v or "") for k, v in r.items() if k is not None} for r in rows]


def skill_labels(num: int, names: Optional[Sequence[str]] = None) -> list[str]:
    """Labels of the N + 1 scheduler choices: the frozen skills' names, then ``new_skill``."""
    names = list(names or [])
    if len(names) == num - 1:
        return names + ["new_skill"]
    return [f"skill_{j}" for j in range(num - 1)] + ["new_skill"]


def avg_consecutive(steps: Sequence[float], runs: Sequence[float]) -> list[float]:
    """Average consecutive execution per skill (env steps per maximal run); NaN without runs."""
    return [s / r if r else math.nan for s, r in zip(steps, runs)]


def scalar_metrics(metrics: dict, skill_names: Optional[Sequence[str]] = None,
                   lengths: Optional[Sequence[int]] = None) -> dict[str, float]:
    """The TensorBoard scalars of one metrics dict (module docstring)."""
    out: dict[str, float] = {}
    for key, value in metrics.items():
        if isinstance(value, bool) or isinstance(value, (int, float)):
            out[key] = float(value)
        elif isinstance(value, list) and value and all(isinstance(v, (int, float)) for v in value):
            if key in ("length_histogram", "length_share") and lengths is not None and len(lengths) == len(value):
                labels = [f"k{k}" for k in lengths]
            elif key.startswith("skill_"):
                labels = skill_labels(len(value), skill_names)
            else:
                labels = [str(j) for j in range(len(value))]
            out.update({f"{key}/{lab}": float(v) for lab, v in zip(labels, value)})
    steps, runs = metrics.get("skill_steps"), metrics.get("skill_runs")
    if isinstance(steps, list) and isinstance(runs, list) and len(steps) == len(runs):
        for lab, v in zip(skill_labels(len(steps), skill_names), avg_consecutive(steps, runs)):
            if math.isfinite(v):
                out[f"skill_avg_consecutive/{lab}"] = v
    return out


# ----------------------------------------------------------------------------- progress


def _duration(seconds: float) -> str:
    seconds = int(max(seconds, 0))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}h{m:02d}m" if h else f"{m}m{s:02d}s"


class Progress:
    """Progress of a run: ``update`` at every evaluation, ``advance`` at every iteration.

    Always one plain line per evaluation on ``out`` (stdout); when ``stream`` (stderr) is a
    terminal, also a progress bar there (env steps, steps/s, ETA, the latest evaluation's
    success), kept below those lines and redrawn every ``tick`` seconds by a daemon thread.
    """

    def __init__(self, total_steps: int, start_steps: int = 0, stream=None, out=None,
                 tty: Optional[bool] = None, width: int = 24, tick: float = 1.0):
        self.stream = stream if stream is not None else sys.stderr
        self.out = out if out is not None else sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)()) if tty is None else tty
        self.total, self.start_steps, self.width = int(total_steps), int(start_steps), width
        self.t0 = time.perf_counter()
        self.steps, self.success = int(start_steps), None
        self._drawn = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker = None
        if self.tty:
            self._draw()
            if tick > 0:
                self._ticker = threading.Thread(target=self._tick, args=(tick,), daemon=True)
                self._ticker.start()

    def _tick(self, every: float):
        while not self._stop.wait(every):
            with self._lock:
                if self._drawn:
                    self._draw()

    def rate(self, steps: int) -> float:
        return (steps - self.start_steps) / max(time.perf_counter() - self.t0, 1e-9)

    @staticmethod
    def line(steps: int, rate: float, m: dict) -> str:
        """The plain per-evaluation line."""
        sched = f" scheduler={m['eval/scheduler_success']:.2f}" if "eval/scheduler_success" in m else ""
        if "eval/scheduler_new_skill_sampled_success" in m:  # greedy, the new skill's actions sampled
            sched += f" scheduler_new_sampled={m['eval/scheduler_new_skill_sampled_success']:.2f}"
        sampled = (f" sampled={m['eval/new_skill_sampled_success']:.2f}" if "eval/new_skill_sampled_success" in m
                   else "")  # the new skill alone with sampled actions
        weighted = (f" critic_weighted={m['eval/new_skill_critic_weighted_success']:.2f}"
                    if "eval/new_skill_critic_weighted_success" in m else "")  # each action picked by its critic
        train = m["episode_success"]  # NaN: no training episode ended since the last line
        train = f"{train:.2f}" if train == train else "n/a"
        return (f"[{steps:>10,d} steps {rate:8,.0f}/s] new_skill success={m['eval/new_skill_success']:.2f}"
                f" return={m['eval/new_skill_return']:.1f}{sampled}{weighted}{sched} train_success={train}"
                f" new_skill_rate={m['new_skill_selection_rate']:.2f}")

    def bar(self) -> str:
        frac = min(max(self.steps / max(self.total, 1), 0.0), 1.0)
        fill = int(round(frac * self.width))
        rate = self.rate(self.steps)
        text = (f"{100 * frac:3.0f}% |{'#' * fill}{'.' * (self.width - fill)}| "
                f"{self.steps:,}/{self.total:,} env steps  {_duration(time.perf_counter() - self.t0)}")
        if self.steps > self.start_steps:
            text += f"  {rate:,.0f} steps/s  ETA {_duration((self.total - self.steps) / max(rate, 1e-9))}"
        else:
            text += "  (compiling; then the first iteration)"
        if self.success is not None:
            text += f"  new_skill success {self.success:.2f}"
        return text

    def _draw(self):
        self.stream.write("\r\x1b[K" + self.bar())
        self.stream.flush()
        self._drawn = True

    def _clear(self):
        if self._drawn:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self._drawn = False

    def advance(self, steps: int):
        """The env steps done so far (the bar shows them at its next redraw)."""
        with self._lock:
            self.steps = int(steps)

    def update(self, steps: int, metrics: dict, prefix: str = ""):
        """An evaluation's line (``prefix``: e.g. the seed of one run among several)."""
        with self._lock:
            self.steps = int(steps)
            self.success = metrics.get("eval/new_skill_success", self.success)
            if self.tty:
                self._clear()
            print(prefix + self.line(self.steps, self.rate(self.steps), metrics), file=self.out, flush=True)
            if self.tty:
                self._draw()

    def close(self):
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        with self._lock:
            if self.tty and self._drawn:
                self.stream.write("\n")
                self.stream.flush()
                self._drawn = False


# ----------------------------------------------------------------------------- TensorBoard


class TensorBoardLogger:
    """Scalars of every evaluation's metrics into ``logdir`` (module docstring).

    ``purge_step``: for a resumed run, the first env step not covered by the checkpoint."""

    def __init__(self, logdir: str, skill_names: Optional[Sequence[str]] = None,
                 lengths: Optional[Sequence[int]] = None, purge_step: Optional[int] = None):
        from tensorboardX import SummaryWriter

        # A file name of its own (tensorboardX names files by the second and opens them "wb").
        suffix = f".{os.getpid()}.{purge_step or 0}"
        self.writer = SummaryWriter(logdir, purge_step=purge_step, filename_suffix=suffix, flush_secs=30)
        self.skill_names, self.lengths = skill_names, lengths

    def log(self, step: int, metrics: dict):
        """Non-finite scalars (episode statistics of an interval in which no episode ended) are left
        out: a gap in the TensorBoard curve; metrics.csv keeps them as nan."""
        for tag, value in scalar_metrics(metrics, self.skill_names, self.lengths).items():
            if math.isfinite(value):
                self.writer.add_scalar(tag, value, int(step))
        self.writer.flush()

    def close(self):
        self.writer.close()


def _records(path: str):
    """Payloads of a TFRecord file (length, masked CRC, data, masked CRC); a torn tail is ignored."""
    with open(path, "rb") as f:
        data = f.read()
    pos = 0
    while pos + 12 <= len(data):
        (length,) = struct.unpack("<Q", data[pos:pos + 8])
        end = pos + 12 + length + 4
        if end > len(data):
            break
        yield data[pos + 12:pos + 12 + length]
        pos = end


def event_files(run_dir: str) -> list[str]:
    """The run's TensorBoard event files, oldest first."""
    files = glob.glob(os.path.join(run_dir, "events.out.tfevents.*"))
    return sorted(files, key=lambda p: (os.path.basename(p).split(".")[3], os.path.getmtime(p), p))


def read_scalars(run_dir: str) -> dict[str, list[tuple[int, float]]]:
    """{tag: [(step, value), ...]} of the run's event files, in order, with TensorBoard's purge
    rule: a session start at step S (a resume) drops the earlier files' events at steps ≥ S."""
    from tensorboardX.proto import event_pb2
    from tensorboardX.proto.event_pb2 import SessionLog

    out: dict[str, list[tuple[int, float]]] = {}
    for path in event_files(run_dir):
        for payload in _records(path):
            ev = event_pb2.Event.FromString(payload)
            if ev.HasField("session_log") and ev.session_log.status == SessionLog.START:
                out = {t: [(s, v) for s, v in pts if s < ev.step] for t, pts in out.items()}
            if ev.HasField("summary"):
                for val in ev.summary.value:
                    out.setdefault(val.tag, []).append((int(ev.step), float(val.simple_value)))
    return out
