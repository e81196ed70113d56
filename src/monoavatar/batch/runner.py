"""``monoavatar batch``: one ``monoavatar COMMAND INPUT -o OUT/<name>`` per input.

Each input runs as its own process (``python -m monoavatar.cli``), so one that fails or
crashes cannot take the others down, and writes exactly what the single command writes (which
stages its files and moves them in only when it succeeds), with its output in
``OUT/<name>/log.txt``. With Ray installed the processes are Ray tasks, on a local cluster
started for the batch or on an existing one (``address``; then ``OUT`` must be a folder every
node sees); without Ray they run one after another on this machine.

``OUT/batch.json`` (rewritten atomically at every change): the command and its options, the
engine, and per input its name, input, output folder, status (``queued``, ``running``,
``done``, ``skipped`` (complete from an earlier run), ``failed``, ``interrupted``), the
error's first line, seconds and exit code. A second run skips the complete folders and runs
the others again.
"""

from __future__ import annotations

import json
import logging
import os
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import IO, Any

from monoavatar.core.errors import MonoavatarError
from monoavatar.core.files import atomic_write_text

__all__ = [
    "COMMANDS",
    "BatchError",
    "BatchItem",
    "BatchResult",
    "BatchSettings",
    "expand_inputs",
    "is_complete",
    "plan_items",
    "run_batch",
]

COMMANDS: dict[str, tuple[str, ...]] = {
    "reconstruct": ("report.json", "avatar.glb"),
    "photo": ("report.json", "avatar.glb"),
    "track": ("report.json", "motion.npz"),
}
"""The commands a batch runs, and the files whose presence marks an output folder complete
(each command moves its files in only after every stage succeeded)."""

LOG = "log.txt"
SUMMARY = "batch.json"
FORMAT = "monoavatar-batch-1"
_THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


class BatchError(MonoavatarError, ValueError):
    """Bad batch input: no inputs, an unreadable list file, an unknown command."""


@dataclass(frozen=True)
class BatchSettings:
    """How a batch runs.

    Attributes:
        command: ``reconstruct``, ``photo`` or ``track``.
        options: the command's own options, as on its command line (e.g. ``["--fast"]``).
        address: an existing Ray cluster (``ray://host:10001`` or ``host:6379``); None: a local
            cluster on this machine's cores.
        cpus_per_task: cores Ray reserves for each input; the command's numerical libraries
            are limited to as many threads.
        use_ray: False runs the inputs one after another without Ray even when it is installed.
        progress: the live table (redrawn on a terminal; one line per change otherwise).
    """

    command: str = "reconstruct"
    options: tuple[str, ...] = ()
    address: str | None = None
    cpus_per_task: int = 1
    use_ray: bool = True
    progress: bool = True

    def validate(self) -> None:
        if self.command not in COMMANDS:
            raise BatchError(f"--command must be one of {', '.join(COMMANDS)}, got "
                             f"{self.command!r}")  # fmt: skip
        if self.cpus_per_task < 1:
            raise BatchError(f"--cpus-per-task must be at least 1, got {self.cpus_per_task}")
        if "-o" in self.options or "--output" in self.options:
            raise BatchError("the output folder of each input is OUT/<name>: give no -o in "
                             "the options")  # fmt: skip


@dataclass
class BatchItem:
    """One input of the batch and what became of it."""

    name: str
    input: str
    output: str
    status: str = "queued"
    error: str = ""
    seconds: float | None = None
    returncode: int | None = None
    stage: str = ""


@dataclass
class BatchResult:
    """The items, the engine that ran them, and the batch's wall-clock seconds."""

    items: list[BatchItem]
    engine: str
    seconds: float
    summary: Path

    @property
    def failed(self) -> list[BatchItem]:
        return [i for i in self.items if i.status in ("failed", "interrupted")]


# -- inputs -----------------------------------------------------------------------------------


def expand_inputs(inputs: Sequence[str | Path]) -> list[Path]:
    """The inputs, a ``.txt`` file replaced by the paths it lists (one a line; blank lines and
    ``#`` comments skipped; relative paths taken from the list's folder).

    Raises:
        BatchError: no inputs at all, or a list file that cannot be read.
    """
    paths: list[Path] = []
    for raw in inputs:
        path = Path(raw)
        if path.suffix.lower() == ".txt" and path.is_file():
            try:
                lines = path.read_text().splitlines()
            except (OSError, UnicodeDecodeError) as exc:
                raise BatchError(f"{path}: cannot read the list of inputs ({exc})") from exc
            for line in lines:
                entry = line.strip()
                if entry and not entry.startswith("#"):
                    listed = Path(entry).expanduser()
                    paths.append(listed if listed.is_absolute() else path.parent / listed)
        else:
            paths.append(path)
    if not paths:
        raise BatchError("no inputs: give videos, image folders, or a .txt file listing them")
    return paths


def plan_items(inputs: Sequence[Path], out_dir: Path) -> list[BatchItem]:
    """One item per input, named after the file's stem or the folder's name (``-2``, ``-3``
    ... where names repeat), its output folder ``out_dir / name``."""
    items: list[BatchItem] = []
    taken: set[str] = set()
    for path in inputs:
        stem = (path.name if path.is_dir() else path.stem) or "input"
        name, k = stem, 1
        while name in taken:
            k += 1
            name = f"{stem}-{k}"
        taken.add(name)
        items.append(BatchItem(name=name, input=str(path), output=str(out_dir / name)))
    return items


def is_complete(folder: str | Path, command: str) -> bool:
    """Whether ``folder`` holds the finished output of ``command``."""
    return all((Path(folder) / f).is_file() for f in COMMANDS[command])


# -- one task ---------------------------------------------------------------------------------


def start_command(args: Sequence[str], log: str | Path, threads: int | None) -> subprocess.Popen:
    """Start ``python -m monoavatar.cli *args`` with its output in ``log`` (created, with the
    command line as its first line); ``threads`` limits the numerical libraries' threads."""
    argv = [sys.executable, "-m", "monoavatar.cli", *args]
    env = dict(os.environ)
    if threads is not None:
        env.update({k: str(threads) for k in _THREAD_VARIABLES})
    log = Path(log)
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "w") as stream:
        stream.write(f"$ monoavatar {shlex.join(args)}\n")
        stream.flush()
        return subprocess.Popen(argv, stdout=stream, stderr=subprocess.STDOUT, env=env,
                                stdin=subprocess.DEVNULL)  # fmt: skip


def stop_command(proc: subprocess.Popen, grace: float = 30.0) -> None:
    """Interrupt a running command as Ctrl-C would (it removes its staged files), killing it
    if it has not stopped after ``grace`` seconds."""
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(grace)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def run_command(args: list[str], log: str, threads: int | None) -> dict[str, Any]:
    """A whole task (what a Ray worker runs): the command to its end; interrupted (a
    cancelled Ray task), it interrupts the command first."""
    start = time.monotonic()
    proc = start_command(args, log, threads)
    try:
        code = proc.wait()
    except BaseException:
        stop_command(proc)
        raise
    return {"returncode": code, "seconds": time.monotonic() - start}


def error_line(log: str | Path) -> str:
    """The first line of the error a command printed (``monoavatar X: error: ...``), else the
    log's last line."""
    try:
        text = Path(log).read_text(errors="replace")
    except OSError:
        return "no log"
    lines = [ln.strip() for ln in text.replace("\r", "\n").splitlines() if ln.strip()]
    for line in reversed(lines):
        if ": error:" in line or line.startswith(("Traceback", "Error", "Exception")):
            return line
    return lines[-1] if lines else "no output"


def current_stage(log: str | Path, width: int = 48) -> str:
    """What a running command shows last (its progress bar or message), one line."""
    try:
        with open(log, "rb") as stream:
            stream.seek(0, os.SEEK_END)
            stream.seek(max(0, stream.tell() - 4096))
            tail = stream.read().decode(errors="replace")
    except OSError:
        return ""
    parts = [p.strip() for p in tail.replace("\r", "\n").split("\n") if p.strip()]
    return parts[-1][:width] if parts else ""


# -- engines ----------------------------------------------------------------------------------


class _Local:
    """The inputs one after another, each a process of its own."""

    name = "local (one after another; install Ray to run inputs side by side)"

    def __init__(self) -> None:
        self.running: dict[str, tuple[subprocess.Popen, float]] = {}

    def capacity(self) -> int:
        return 1 - len(self.running)

    def submit(self, item: BatchItem, args: list[str]) -> None:
        proc = start_command(args, Path(item.output) / LOG, None)
        self.running[item.name] = (proc, time.monotonic())

    def finished(self, timeout: float) -> list[tuple[str, dict[str, Any]]]:
        deadline = time.monotonic() + timeout
        while True:
            done = [(n, p, t) for n, (p, t) in self.running.items() if p.poll() is not None]
            if done or time.monotonic() >= deadline:
                break
            time.sleep(0.1)
        out = []
        for name, proc, t0 in done:
            del self.running[name]
            out.append((name, {"returncode": proc.returncode,
                               "seconds": time.monotonic() - t0}))  # fmt: skip
        return out

    def started(self, item: BatchItem) -> bool:
        return item.name in self.running

    def cancel(self) -> None:
        for proc, _ in self.running.values():
            try:
                proc.wait(5.0)  # Ctrl-C on a terminal reached the command too
            except subprocess.TimeoutExpired:
                stop_command(proc)

    def close(self) -> None:
        pass


class _Ray:
    """Every input a Ray task of ``cpus_per_task`` cores."""

    def __init__(self, settings: BatchSettings) -> None:
        import ray

        self.ray = ray
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                      "logging_level": logging.ERROR}  # fmt: skip
            if settings.address is None:
                kwargs["num_cpus"] = os.cpu_count() or 1
            ray.init(address=settings.address, **kwargs)
        cpus = int(ray.cluster_resources().get("CPU", 0))
        if cpus < settings.cpus_per_task:
            raise BatchError(f"the Ray cluster has {cpus} CPUs, fewer than --cpus-per-task "
                             f"{settings.cpus_per_task}")  # fmt: skip
        where = settings.address or "a local cluster"
        per = settings.cpus_per_task
        self.name = f"ray {ray.__version__} on {where} ({cpus} CPUs, {per} a task)"
        self.task = ray.remote(num_cpus=settings.cpus_per_task, max_retries=0)(run_command)
        self.threads = settings.cpus_per_task
        self.refs: dict[Any, str] = {}

    def capacity(self) -> int:
        return 1 << 30  # Ray queues the tasks itself

    def submit(self, item: BatchItem, args: list[str]) -> None:
        ref = self.task.remote(args, str(Path(item.output) / LOG), self.threads)
        self.refs[ref] = item.name

    def finished(self, timeout: float) -> list[tuple[str, dict[str, Any]]]:
        if not self.refs:
            return []
        ready, _ = self.ray.wait(list(self.refs), num_returns=len(self.refs), timeout=timeout)
        out = []
        for ref in ready:
            name = self.refs.pop(ref)
            try:
                out.append((name, self.ray.get(ref)))
            except Exception as exc:  # noqa: BLE001 - a worker that died: that input failed
                error = f"the Ray task failed: {type(exc).__name__}"
                out.append((name, {"returncode": -1, "seconds": None, "error": error}))
        return out

    def started(self, item: BatchItem) -> bool:
        return (Path(item.output) / LOG).is_file()

    def cancel(self) -> None:
        for ref in list(self.refs):
            self.ray.cancel(ref)
        if self.refs:
            self.ray.wait(list(self.refs), num_returns=len(self.refs), timeout=60)

    def close(self) -> None:
        self.ray.shutdown()


def _engine(settings: BatchSettings, say: Callable[[str], None]) -> _Local | _Ray:
    if not settings.use_ray:
        if settings.address is not None:
            raise BatchError("--address needs Ray")
        return _Local()
    try:
        import ray  # noqa: F401
    except ImportError:
        if settings.address is not None:
            raise BatchError("--address needs Ray: pip install 'monoavatar[ray]'") from None
        say("Ray is not installed: the inputs run one after another "
            "(pip install 'monoavatar[ray]' to run them side by side or on a cluster)")
        return _Local()
    return _Ray(settings)


# -- the table --------------------------------------------------------------------------------


class _Table:
    """Per-input status: redrawn in place on a terminal, a line per change otherwise."""

    def __init__(self, items: list[BatchItem], stream: IO[str], enabled: bool) -> None:
        self.items, self.stream, self.enabled = items, stream, enabled
        self.tty = enabled and stream.isatty()
        self.drawn = 0
        self.last: dict[str, str] = {}
        self.width = max(len(i.name) for i in items)

    def row(self, item: BatchItem) -> str:
        note = item.error if item.status in ("failed", "interrupted") else item.stage
        secs = f"{item.seconds:6.0f} s" if item.seconds is not None else " " * 8
        return f"{item.name:<{self.width}}  {item.status:<11} {secs}  {note}"

    def update(self) -> None:
        if not self.enabled:
            return
        if self.tty:
            if self.drawn:
                self.stream.write(f"\x1b[{self.drawn}F\x1b[J")
            done = sum(i.status in ("done", "skipped") for i in self.items)
            lines = [self.row(i) for i in self.items] + [f"{done}/{len(self.items)} done"]
            self.stream.write("\n".join(lines) + "\n")
            self.drawn = len(lines)
        else:
            for item in self.items:
                if self.last.get(item.name) != item.status:
                    self.last[item.name] = item.status
                    self.stream.write(self.row(item).rstrip() + "\n")
        self.stream.flush()


# -- the batch --------------------------------------------------------------------------------


def _write_summary(path: Path, settings: BatchSettings, engine: str, items: list[BatchItem],
                   seconds: float) -> None:  # fmt: skip
    record = {"format": FORMAT, "command": settings.command, "options": list(settings.options),
              "engine": engine, "seconds": seconds,
              "items": [{k: v for k, v in asdict(i).items() if k != "stage"} for i in items]}
    atomic_write_text(path, json.dumps(record, indent=2))


def run_batch(inputs: Sequence[str | Path], out_dir: str | Path,
              settings: BatchSettings | None = None, *,
              stream: IO[str] | None = None) -> BatchResult:  # fmt: skip
    """Run ``settings.command`` on every input into ``out_dir/<name>/`` (see the module
    docstring); inputs whose folder is already complete are skipped.

    Raises:
        BatchError: bad settings or inputs; KeyboardInterrupt: after the running commands
        were interrupted and ``batch.json`` written.
    """
    settings = settings or BatchSettings()
    settings.validate()
    stream = stream or sys.stdout
    out = Path(out_dir)
    items = plan_items(expand_inputs(inputs), out)
    out.mkdir(parents=True, exist_ok=True)
    summary = out / SUMMARY
    start = time.monotonic()
    for item in items:
        if is_complete(item.output, settings.command):
            item.status = "skipped"
    todo = [i for i in items if i.status == "queued"]

    def say(message: str) -> None:
        if settings.progress:
            stream.write(message + "\n")
            stream.flush()

    engine = _engine(settings, say) if todo else _Local()
    engine_name = engine.name if todo else "none (every input was complete)"
    say(f"monoavatar batch: {len(items)} inputs ({len(items) - len(todo)} complete already), "
        f"{settings.command}, {engine_name}")
    table = _Table(items, stream, settings.progress)
    by_name = {i.name: i for i in items}
    for item in todo:  # a log of an earlier failed run says nothing about this one
        (Path(item.output) / LOG).unlink(missing_ok=True)
    pending = list(todo)
    try:
        while pending or any(i.status in ("queued", "running") for i in todo):
            while pending and engine.capacity() > 0:
                item = pending.pop(0)
                args = [settings.command, item.input, "-o", item.output, *settings.options]
                engine.submit(item, args)
            for name, outcome in engine.finished(0.5):
                _finish(by_name[name], outcome, settings.command)
                _write_summary(summary, settings, engine_name, items, time.monotonic() - start)
            for item in todo:
                if item.status in ("queued", "running") and engine.started(item):
                    if item.status == "queued":
                        item.status = "running"
                        _write_summary(summary, settings, engine_name, items,
                                       time.monotonic() - start)  # fmt: skip
                    item.stage = current_stage(Path(item.output) / LOG)
            table.update()
    except BaseException:
        engine.cancel()
        for item in todo:
            if item.status == "running":
                item.status, item.error = "interrupted", "the batch was interrupted"
        _write_summary(summary, settings, engine_name, items, time.monotonic() - start)
        engine.close()
        raise
    engine.close()
    seconds = time.monotonic() - start
    _write_summary(summary, settings, engine_name, items, seconds)
    table.update()
    return BatchResult(items, engine_name, seconds, summary)


def _finish(item: BatchItem, outcome: dict[str, Any], command: str) -> None:
    """Record a finished task: done only with a complete output folder."""
    item.returncode = int(outcome["returncode"])
    item.seconds = outcome.get("seconds")
    item.stage = ""
    log = Path(item.output) / LOG
    if item.returncode == 0 and is_complete(item.output, command):
        item.status = "done"
    elif item.returncode == 130:
        item.status, item.error = "interrupted", "interrupted"
    else:
        item.status = "failed"
        item.error = outcome.get("error") or (error_line(log) if item.returncode != 0 else
                                              "finished without its output files")  # fmt: skip

