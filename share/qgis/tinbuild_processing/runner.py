"""Runs the tinbuild executable for the Processing algorithms.

Every algorithm of the provider is a command line: it finds the executable, checks its version, starts
it with `--progress json` and passes what it prints on to the Processing feedback, while it watches the
feedback's Cancel.

- **Finding it.** The provider's setting (Settings > Options > Processing > Providers > tinbuild) names
  the executable; when it is empty, `tinbuild` is looked up on PATH.  A setting naming a file that is not
  there (or not executable), no tinbuild on PATH, and a tinbuild older than MIN_VERSION are errors that
  say so and what to do.  `tinbuild --version` prints `tinbuild X.Y.Z`; its answer is remembered per
  path and modification time, so a run costs one version check per new or rebuilt executable.
- **Progress.** With `--progress json`, tinbuild writes one JSON object a line on stderr:
  `stage`, `complete` (0..1), `points_done`, `points_total`, `points_per_second`, `elapsed_seconds`,
  `eta_seconds`, `rss_bytes`.  `complete` drives the dialog's bar, a new `stage` becomes the progress
  text (which the dialog also logs).  Its other stderr lines are the summary (into the log), warnings
  (`tinbuild: warning: ...`, as warnings) and errors (`tinbuild: error: ...`, kept for the exception).
- **Cancel.** The feedback is polled every 0.1 s; when it is cancelled, tinbuild gets SIGTERM once.
  Its contract (docs/usage.md) is to stop within a fraction of a second, remove its temporaries and
  exit with code 3, leaving no final-named output.  The runner waits for that exit (SIGKILL only after
  KILL_AFTER seconds, which the contract never needs) and raises QgsProcessingException.
- **Failure.** A non-zero exit raises QgsProcessingException whose message is tinbuild's own error
  lines (`tinbuild: error: FILE: what is wrong`), or its last stderr lines when it printed none.

Two threads read stdout and stderr into one queue so that neither pipe can fill and block tinbuild;
only the calling thread (the algorithm's) touches the feedback.
"""
import json
import os
import queue
import re
import shutil
import signal
import subprocess
import threading
import time

from qgis.core import QgsProcessingException

MIN_VERSION = (0, 1, 0)
SETTING_EXECUTABLE = 'TINBUILD_EXECUTABLE'
POLL_SECONDS = 0.1
KILL_AFTER = 60.0

_versionCache = {}


def versionText(version):
    return '.'.join(str(v) for v in version)


def parseVersion(text):
    """(major, minor, patch) from `tinbuild --version`'s `tinbuild 0.1.0`, or None."""
    m = re.search(r'\btinbuild\s+(\d+)\.(\d+)(?:\.(\d+))?', text or '')
    if not m:
        return None
    return (int(m.group(1)), int(m.group(2)), int(m.group(3) or 0))


def configuredExecutable():
    """The provider's setting (a path, or '' for PATH); '' when Processing's settings are unavailable."""
    try:
        from processing.core.ProcessingConfig import ProcessingConfig
    except ImportError:
        return ''
    value = ProcessingConfig.getSetting(SETTING_EXECUTABLE)
    return str(value).strip() if value else ''


def findExecutable(configured=None):
    """The executable's absolute path; QgsProcessingException with what to do when there is none."""
    if configured is None:
        configured = configuredExecutable()
    where = ('Set its path in Settings > Options > Processing > Providers > tinbuild > '
             '"tinbuild executable", or leave that empty to use the tinbuild found on PATH.')
    if configured:
        path = os.path.expanduser(configured)
        if not os.path.isfile(path):
            raise QgsProcessingException(
                f'The tinbuild executable is not there: the provider\'s setting names {path}, which does not '
                f'exist. {where}')
        if not os.access(path, os.X_OK):
            raise QgsProcessingException(
                f'The tinbuild executable {path} (the provider\'s setting) cannot be run: it is not '
                f'executable. {where}')
        return os.path.abspath(path)
    found = shutil.which('tinbuild')
    if not found:
        raise QgsProcessingException(
            'The tinbuild executable was not found: there is no tinbuild on PATH and the provider\'s '
            f'setting is empty. Install tinbuild (build it from its sources: cmake --build build '
            f'--target tinbuild) and put it on PATH. {where}')
    return os.path.abspath(found)


def checkVersion(exe):
    """The executable's version tuple; QgsProcessingException when it cannot tell or is too old."""
    try:
        key = (exe, os.stat(exe).st_mtime_ns)
    except OSError as e:
        raise QgsProcessingException(f'Cannot run tinbuild at {exe}: {e.strerror}')
    if key in _versionCache:
        version = _versionCache[key]
    else:
        try:
            r = subprocess.run([exe, '--version'], capture_output=True, text=True, timeout=30,
                               stdin=subprocess.DEVNULL)
        except (OSError, subprocess.TimeoutExpired) as e:
            raise QgsProcessingException(f'Cannot run tinbuild at {exe} (`tinbuild --version`): {e}')
        version = parseVersion(r.stdout) or parseVersion(r.stderr)
        if version is None:
            raise QgsProcessingException(
                f'{exe} does not answer `--version` like tinbuild ("tinbuild X.Y.Z"); this plugin needs '
                f'tinbuild {versionText(MIN_VERSION)} or newer. It said: '
                f'{(r.stdout + r.stderr).strip()[:200]!r}')
        _versionCache[key] = version
    if version < MIN_VERSION:
        raise QgsProcessingException(
            f'tinbuild {versionText(version)} at {exe} is too old: this plugin needs tinbuild '
            f'{versionText(MIN_VERSION)} or newer. Install a newer tinbuild, or point the provider\'s '
            f'setting (Settings > Options > Processing > Providers > tinbuild) at one.')
    return version


def executable():
    """The checked executable (found, and new enough): (path, version)."""
    exe = findExecutable()
    return exe, checkVersion(exe)


def quoteArgs(args):
    import shlex
    return ' '.join(shlex.quote(str(a)) for a in args)


def _reader(stream, name, q):
    try:
        for line in iter(stream.readline, ''):
            q.put((name, line.rstrip('\n')))
    finally:
        q.put((name, None))


def run(args, feedback, exe=None):
    """Runs `tinbuild ARGS`; returns its stdout.  Raises QgsProcessingException on failure or cancel.

    `feedback` is a QgsProcessingFeedback (or None).  ARGS should hold `--progress json` for commands
    that report progress (`build`); those that do not (`info`) simply show no bar movement.
    """
    if exe is None:
        exe, _ = executable()
    cmd = [exe] + [str(a) for a in args]
    if feedback is not None:
        feedback.pushCommandInfo(quoteArgs(cmd))
    try:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, bufsize=1, errors='replace')
    except OSError as e:
        raise QgsProcessingException(f'Cannot start tinbuild ({exe}): {e.strerror}')

    q = queue.Queue()
    threads = [threading.Thread(target=_reader, args=(proc.stdout, 'stdout', q), daemon=True),
               threading.Thread(target=_reader, args=(proc.stderr, 'stderr', q), daemon=True)]
    for t in threads:
        t.start()

    stdout = []
    errors = []
    tail = []
    stage = None
    open_streams = 2
    terminated_at = None
    killed = False
    while open_streams > 0 or proc.poll() is None:
        if feedback is not None and feedback.isCanceled() and terminated_at is None and proc.poll() is None:
            feedback.pushInfo('Cancelled: stopping tinbuild (SIGTERM); it removes its temporary outputs')
            proc.send_signal(signal.SIGTERM)
            terminated_at = time.monotonic()
        if terminated_at is not None and not killed and proc.poll() is None \
                and time.monotonic() - terminated_at > KILL_AFTER:
            proc.kill()
            killed = True
        try:
            name, line = q.get(timeout=POLL_SECONDS)
        except queue.Empty:
            continue
        if line is None:
            open_streams -= 1
            continue
        if name == 'stdout':
            stdout.append(line)
            continue
        stripped = line.strip()
        if stripped.startswith('{'):
            try:
                event = json.loads(stripped)
            except ValueError:
                event = None
            if isinstance(event, dict) and 'complete' in event:
                if feedback is not None:
                    feedback.setProgress(max(0.0, min(100.0, 100.0 * float(event.get('complete') or 0))))
                    if event.get('stage') and event.get('stage') != stage:
                        # (the dialog logs the progress text too: one line per stage)
                        stage = event['stage']
                        total = event.get('points_total')
                        counted = stage.startswith('pass') and isinstance(total, int) and total
                        feedback.setProgressText(stage + (f' ({total:,} points)' if counted else ''))
                continue
        if not stripped:
            continue
        tail = (tail + [stripped])[-8:]
        if stripped.startswith('tinbuild: error:'):
            errors.append(stripped)
        elif feedback is not None:
            if stripped.startswith('tinbuild: warning:') and hasattr(feedback, 'pushWarning'):
                feedback.pushWarning(stripped)
            else:
                feedback.pushInfo(line.rstrip())
    rc = proc.wait()
    for t in threads:
        t.join(timeout=5)
    proc.stdout.close()
    proc.stderr.close()

    if terminated_at is not None and rc == 0:
        # The signal came after tinbuild's commit step had begun: the run is whole and its outputs stay
        # (the exit code always agrees with the result).
        if feedback is not None:
            feedback.pushInfo('Cancel came too late: tinbuild had already finished and kept its outputs')
    elif terminated_at is not None or rc == 3:
        why = 'Cancelled' if terminated_at is not None else 'tinbuild was stopped by a signal'
        if killed:
            raise QgsProcessingException(f'{why}: tinbuild did not stop within {KILL_AFTER:.0f} s of SIGTERM and was '
                            f'killed; its temporary files may be left beside the outputs (the next run on them '
                            f'removes them)')
        raise QgsProcessingException(f'{why}: tinbuild stopped (exit code {rc}) and left no output')
    elif rc != 0:
        message = '\n'.join(errors) if errors else '\n'.join(tail) or 'no message'
        kind = {1: 'a data or runtime error', 2: 'a usage error'}.get(rc, f'exit code {rc}')
        raise QgsProcessingException(f'{message}\n(tinbuild failed: {kind}, exit code {rc})')
    if feedback is not None:
        feedback.setProgress(100.0)
    return '\n'.join(stdout)
