"""The ``hd`` command's terminal: one-line errors, clean stops on signals, summaries and progress.

Every command turns bad input into a one-line error and a non-zero exit status. Ctrl-C, SIGTERM
and SIGHUP stop a command cleanly (partial files removed, resumable; a second signal does not
interrupt the clean-up) with exit status 128 + the signal number: 130, 143, 129
(docs/reliability.md). ``hd -q``, ``hd --no-progress`` and ``hd --json`` choose what is written
(:data:`OUTPUT`). Every error, warning, summary and JSON record is written with each URL in it in its
printable form (``hdcore.redact.redact_urls``: no password, no query value), whatever named it.
"""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Callable, Mapping
from functools import wraps
from typing import Any

import click
from click.core import ParameterSource

from hdcore.errors import HdError, HdWarning
from hdcore.redact import redact_urls
from hdnet.checkpoint_json import EpochProgress, EpochRow


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised in the main thread so that it unwinds like Ctrl-C."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
# The stop signal being handled (0 while none): from then on the process only stops.
_stopping: list[int] = [0]


def _ignore(signum: int, frame: Any) -> None:
    """A signal after the first: the clean-up goes on. (A Python no-op, not SIG_IGN: signals already
    pending when the handler changes to SIG_IGN make CPython raise "ignored due to race condition".)"""


def _ignore_stop_signals_until_exit() -> None:
    """At exit after a stop signal: the kernel ignores further ones (SIG_IGN, which the interpreter's
    shutdown keeps; a Python handler would be reset to SIG_DFL, and a signal then would end the
    process with -signum instead of 128 + signum). A signal already received but not yet handled
    by Python is dropped quietly instead of printing "ignored due to race condition"."""
    previous_hook = sys.unraisablehook

    def hook(unraisable: Any) -> None:
        value = unraisable.exc_value
        if isinstance(value, OSError) and "ignored due to race condition" in str(value):
            return
        previous_hook(unraisable)

    sys.unraisablehook = hook
    for sig in _STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)


def _raise_terminated(signum: int, frame: Any) -> None:
    for sig in _STOP_SIGNALS:  # a second signal (Ctrl-C pressed twice) must not interrupt the clean-up
        signal.signal(sig, _ignore)
    if not _stopping[0]:
        import atexit

        _stopping[0] = signum
        atexit.register(_ignore_stop_signals_until_exit)  # runs first: atexit calls in reverse order
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signum)


def install_signal_handlers(ctx: click.Context) -> None:
    """Ctrl-C, SIGTERM and SIGHUP unwind as KeyboardInterrupt, once. The previous handlers are
    restored when the command ends, unless it was stopped: then any number of further signals
    is ignored until the process exits with 128 + the first one."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        return
    previous = {sig: signal.signal(sig, _raise_terminated) for sig in _STOP_SIGNALS}

    def restore() -> None:
        if not _stopping[0]:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    ctx.call_on_close(restore)


def install_warning_format() -> None:
    """hd's own warnings (``HdWarning``) as one ``Warning: ...`` line on standard error; others as usual."""
    import warnings

    default = warnings.showwarning

    def show(message: Any, category: Any, filename: str, lineno: int, file: Any = None, line: Any = None) -> None:
        if isinstance(category, type) and issubclass(category, HdWarning):
            click.echo(f"Warning: {one_line(Exception(str(message)))}", err=True)
        else:
            default(message, category, filename, lineno, file, line)

    warnings.showwarning = show


def one_line(exc: BaseException) -> str:
    """The message of an error as one line (a DataLoader worker's error carries its traceback); control
    characters that a terminal would break the line at, or act on, which user text (a name, a path)
    can carry into a message, are shown escaped (``\\r``); a URL is shown without its secrets."""
    text = str(exc).strip()
    if "Original Traceback" in text:
        text = text.splitlines()[-1].split(": ", 1)[-1]
    if "\n" in text:
        text = " ".join(text.split())
    return redact_urls(text).translate(_ESCAPED_CONTROLS)


# Every C0 and C1 control character, DEL and the Unicode line and paragraph separators, but the tab.
_ESCAPED_CONTROLS = {c: ascii(chr(c))[1:-1] for c in (*range(0x20), *range(0x7F, 0xA0), 0x2028, 0x2029) if c != 0x09}


def _close_progress_bars() -> None:
    """End every open tqdm bar (with its newline), so that an error starts on its own line."""
    try:
        from tqdm import tqdm
    except ImportError:
        return
    for bar in list(getattr(tqdm, "_instances", [])):
        with contextlib.suppress(Exception):  # a bar that cannot close must not hide the error
            bar.close()


# The commands (their callbacks, as ``friendly_errors`` returns them) that honour ``hd --json``.
_JSON_COMMANDS: set[Callable[..., Any]] = set()


def json_output(command: Callable[..., Any]) -> Callable[..., Any]:
    """Mark a command (above its ``@friendly_errors``) as one that prints its summary as JSON with
    ``hd --json``; every other command refuses the flag."""
    _JSON_COMMANDS.add(command)
    return command


def _refuse_json_unless(command: Callable[..., Any]) -> None:
    """``hd --json`` with a command that has no JSON output: a usage error, never silently ignored."""
    if OUTPUT.json and command not in _JSON_COMMANDS:
        path = click.get_current_context().command_path
        raise click.UsageError(f"{path} has no JSON output; run it without --json")


def friendly_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn the packages' input errors into click errors: one line, exit status 1, no traceback.
    ``hd --json`` is refused first unless the command is marked with :func:`json_output`."""

    @wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        _refuse_json_unless(command)
        try:
            return func(*args, **kwargs)
        except BaseException:
            _close_progress_bars()
            raise

    command = _one_line_errors(wrapper)
    return command


def _one_line_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    @wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except HdError as exc:
            raise click.ClickException(one_line(exc)) from exc
        except OSError as exc:
            from hdcore.storage import describe_os_error

            raise click.ClickException(redact_urls(describe_os_error(exc))) from exc
        except MemoryError as exc:
            raise click.ClickException(
                "out of memory; use smaller settings (fewer scans per shard, a smaller batch or resolution)"
            ) from exc
        except KeyboardInterrupt as exc:
            signum = getattr(exc, "signum", signal.SIGINT)
            what = "interrupted" if signum == signal.SIGINT else f"stopped by {signal.Signals(signum).name}"
            click.echo(f"\n{what}; re-run the same command to resume", err=True)
            sys.exit(128 + int(signum))

    return wrapper


def refuse_with_recipe(ctx: click.Context, names: set[str], what: str, error: type[HdError]) -> None:
    """A recipe fixes the settings ``names``: refuse any of them given on the command line."""
    given = [
        p
        for p in ctx.command.params
        if p.name in names and ctx.get_parameter_source(p.name) is ParameterSource.COMMANDLINE
    ]
    if given:
        flags = ", ".join(p.opts[0] for p in given)
        raise error(f"--recipe fixes {what}; edit the recipe instead of passing {flags}")


class Output:
    """How the commands write to the terminal (``hd -q``, ``hd --no-progress``; docs/user-guide.md,
    "Scripting"): ``quiet`` drops the summaries, ``progress`` the progress bars; ``lines`` writes
    progress as plain lines (at most one per tenth of the work) when stderr is not a terminal, so
    that log files get no carriage-return updates."""

    quiet = False
    progress = True
    lines = False
    json = False


OUTPUT = Output()


def restore_env(name: str, value: str | None) -> None:
    import os

    if value is None:
        os.environ.pop(name, None)
    else:
        os.environ[name] = value


def epoch_lines(row: EpochRow, total: int) -> None:
    """One log line per finished training epoch (progress when stderr is not a terminal)."""
    click.echo(
        f"train: epoch {int(row['epoch'])}/{total}, train loss {row['train_loss']:.4f}, val loss "
        f"{row['val_loss']:.4f}, val PA {row['val_pixel_accuracy']:.4f}, {row['train_images_per_s']:.1f} images/s",
        err=True,
    )


def epoch_progress() -> EpochProgress:
    """How a training shows its epochs (``hd train`` and the training stage of ``hd demo`` and
    ``hd reproduce``): a bar on a terminal, :func:`epoch_lines` in a log, nothing with ``-q`` or
    ``--no-progress``."""
    if not OUTPUT.progress:
        return False
    return epoch_lines if OUTPUT.lines else True


def say(text: str) -> None:
    """A command's summary on stdout, unless ``hd -q`` or ``hd --json`` (whose record replaces it);
    a progress bar still open is ended first, so that the summary starts on its own line."""
    if not (OUTPUT.quiet or OUTPUT.json):
        _close_progress_bars()
        click.echo(redact_urls(text))


def record(record: Mapping[str, object]) -> None:
    """A command's summary as one JSON object on stdout, with ``hd --json`` (even with ``-q``), after
    any progress bar still open is ended."""
    if OUTPUT.json:
        import json

        from hdnet.report import json_plain

        _close_progress_bars()
        click.echo(redact_urls(json.dumps(json_plain(record), default=str)))  # paths as strings


class ScanProgress:
    """Progress fed with (done, total) counts of scans (or of another ``unit``): a tqdm bar on a
    terminal, plain lines in a log, nothing with ``hd -q`` or ``--no-progress``."""

    def __init__(self, desc: str, unit: str = "scan") -> None:
        self.desc = desc
        self.unit = unit
        self.bar: Any = None
        self.tenth = -1

    def __call__(self, done: int, total: int) -> None:
        from tqdm import tqdm

        if not OUTPUT.progress:
            return
        if OUTPUT.lines:
            tenth = 10 * done // total if total > 0 else 10
            if tenth > self.tenth:
                self.tenth = tenth
                click.echo(f"{self.line(done, total)} ({100 * done // max(total, 1)}%)", err=True)
            return
        if self.bar is None:
            self.bar = tqdm(total=total, initial=done, desc=self.desc, unit=self.unit, dynamic_ncols=True)
        else:
            self.bar.update(done - self.bar.n)

    def line(self, done: int, total: int) -> str:
        """``descents: 20/200``, or ``eval: 3/8 images`` where the name does not say the unit already."""
        unit = "" if self.desc == f"{self.unit}s" else f" {self.unit}s"
        return f"{self.desc}: {done}/{total}{unit}"

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def __enter__(self) -> ScanProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class HdGroup(click.Group):
    """The ``hd`` group: a usage error is one line (``Error: ... (see 'hd CMD --help')``, exit 2)
    instead of click's usage block; everything else as click's standalone mode."""

    def main(
        self,
        args: Any = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        **extra: Any,
    ) -> Any:
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        try:
            super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.UsageError as exc:
            hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
            click.echo(f"Error: {one_line(Exception(exc.format_message()))}{hint}", err=True)
            sys.exit(exc.exit_code)
        except click.ClickException as exc:
            exc.show()
            sys.exit(exc.exit_code)
        except click.exceptions.Exit as exc:
            sys.exit(exc.exit_code)
        except click.exceptions.Abort:
            click.echo("Aborted!", err=True)
            sys.exit(1)
        sys.exit(0)


def start(ctx: click.Context, quiet: bool, no_progress: bool, as_json: bool) -> None:
    """Set up a command's terminal: what is written (``hd -q``, ``--no-progress``, ``--json``; plain
    progress lines when standard error is not a terminal), signal handlers and warning format."""
    import os

    from lidarsim.parallel import forked_children_die_with_parent

    OUTPUT.quiet = quiet
    OUTPUT.json = as_json
    OUTPUT.progress = not (quiet or no_progress or os.environ.get("TQDM_DISABLE", "") not in ("", "0"))
    OUTPUT.lines = not sys.stderr.isatty()
    if not OUTPUT.progress or OUTPUT.lines:  # the library's own bars (training) too, for this command
        before = os.environ.get("TQDM_DISABLE")
        os.environ["TQDM_DISABLE"] = "1"
        ctx.call_on_close(lambda: restore_env("TQDM_DISABLE", before))

    install_signal_handlers(ctx)
    install_warning_format()
    forked_children_die_with_parent()
