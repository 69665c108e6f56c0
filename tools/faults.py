"""``make faults``: SIGKILL a replay at random moments and check that every run folder it leaves
reads back consistently and that the report takes it as a partial run.

Each kill starts ``phrt render SCENE --out DIR/kill-NN`` (a HYBRID replay, EXR images) and kills
it with SIGKILL at one of these moments, in turn:

- ``image``: when a frame's image appears under its temporary name in ``frames/`` (inotify
  IN_CREATE: Blender has just begun writing it);
- ``csv``: when ``frames.csv`` or ``selection.csv`` is written to (IN_MODIFY: a row is being
  written);
- ``summary``: when ``summary.json``'s temporary file appears (IN_CREATE);
- ``random``: a random time after the run's first ``summary.json``.

Which event of its kind triggers the kill is drawn at random (the first to the fifth), so
kills land on different frames.  The kill is sent the moment the event is read: the process
may have got a little further by then, which is what a real kill does too.  Every fourth
kill reuses the folder of the kill before it with ``--overwrite`` (the dead writer's lock is
taken over and its files removed first).

After each kill the folder must read back consistently: ``summary.json`` says partial and its
frame count equals the complete ``frames.csv`` rows read and the complete images read, the
first frames of the range in order, with selection rows of those frames only; no file under
a final name is incomplete.  The report of the killed run beside a complete raytrace
reference run must build and say the run is partial.

``python tools/faults.py --kills 20 --out out/faults`` (``make faults``); the tests run a short
version (``tests/integration/test_faults.py``).  Linux only (inotify).  Exit status 1 if a
folder is inconsistent.
"""
from __future__ import annotations

import argparse
import ctypes
import os
import random
import select
import shutil
import signal
import struct
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MOMENTS = ("image", "csv", "summary", "random")
IN_MODIFY, IN_CREATE = 0x2, 0x100
RENDER_ARGS = ("--resolution", "64x48", "--mode", "hybrid", "--images", "exr")


class _Inotify:
    """The Linux inotify API through ctypes: watch folders, read (folder, name, mask) events."""

    def __init__(self):
        self.libc = ctypes.CDLL(None, use_errno=True)
        self.fd = self.libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
        if self.fd < 0:
            raise OSError(ctypes.get_errno(), "inotify_init1 failed")
        self.watches = {}

    def watch(self, folder: Path, mask: int):
        descriptor = self.libc.inotify_add_watch(self.fd, str(folder).encode(), mask)
        if descriptor >= 0:
            self.watches[descriptor] = folder
        return descriptor >= 0

    def events(self, timeout_s: float):
        ready, _, _ = select.select([self.fd], [], [], timeout_s)
        if not ready:
            return []
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return []
        found, offset = [], 0
        while offset + 16 <= len(data):
            descriptor, mask, _, length = struct.unpack_from("iIII", data, offset)
            name = data[offset + 16: offset + 16 + length].split(b"\0", 1)[0].decode(errors="replace")
            found.append((self.watches.get(descriptor), name, mask))
            offset += 16 + length
        return found

    def close(self):
        os.close(self.fd)


def _phrt() -> list:
    found = Path(sys.executable).with_name("phrt")
    return [str(found)] if found.exists() else [sys.executable, "-m", "phrt.cli"]


def _matches(moment: str, folder: Path, run_dir: Path, name: str, mask: int) -> bool:
    if moment == "image":
        return folder == run_dir / "frames" and mask & IN_CREATE and ".partial" in name
    if moment == "csv":
        return folder == run_dir and mask & IN_MODIFY and name in ("frames.csv", "selection.csv")
    if moment == "summary":
        return folder == run_dir and mask & IN_CREATE and name.startswith("summary.json.tmp")
    return False


@dataclass
class Kill:
    number: int
    moment: str
    run_dir: Path
    overwrite: bool
    killed: bool = False  # False: the replay ended before the moment came
    frames: int = 0
    problems: list = field(default_factory=list)


def kill_once(scene: str, run_dir: Path, moment: str, rng: random.Random, frames: str, overwrite: bool,
              timeout_s: float = 300.0, max_skip: int = 5, max_delay_s: float = 4.0) -> bool:
    """Start a replay into ``run_dir`` and SIGKILL it at ``moment``; True if it was killed."""
    argv = _phrt() + ["render", scene, "--frames", frames, "--out", str(run_dir), *RENDER_ARGS]
    if overwrite:
        argv.append("--overwrite")
    process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    notify = _Inotify()
    skip = rng.randrange(max_skip)  # which event of its kind kills: spread over frames
    delay = rng.uniform(0.0, max_delay_s)
    deadline = time.monotonic() + timeout_s
    watched = set()
    summary_seen_at = None
    try:
        while time.monotonic() < deadline and process.poll() is None:
            for folder in (run_dir, run_dir / "frames"):
                if folder not in watched and folder.is_dir() and notify.watch(folder, IN_CREATE | IN_MODIFY):
                    watched.add(folder)
            for folder, name, mask in notify.events(0.01):
                if summary_seen_at is None and folder == run_dir and name.startswith("summary.json"):
                    summary_seen_at = time.monotonic()
                if moment != "random" and _matches(moment, folder, run_dir, name, mask):
                    if skip == 0:
                        process.send_signal(signal.SIGKILL)
                        process.wait()
                        return True
                    skip -= 1
            if moment == "random" and summary_seen_at is not None and time.monotonic() - summary_seen_at >= delay:
                process.send_signal(signal.SIGKILL)
                process.wait()
                return True
        if process.poll() is None:
            process.kill()
            raise RuntimeError(f"the replay into {run_dir} did not reach its {moment} moment in {timeout_s:.0f} s")
        if process.returncode != 0:
            raise RuntimeError(f"the replay into {run_dir} failed before it was killed ({process.returncode}): "
                               f"{process.stderr.read().strip().splitlines()[-1:]}")
        return False
    finally:
        notify.close()
        if process.poll() is None:
            process.kill()
        process.wait()


def check_folder(run_dir: Path, reference_dir: Path, first_frame: int, killed: bool, report_dir: Path) -> list:
    """What is inconsistent in a killed run's folder (empty when nothing is)."""
    from phrt.phrt_addon import report
    from phrt.phrt_addon.runs import run_files as reader

    problems = []
    try:
        summary = reader.read_summary(run_dir)
    except FileNotFoundError:
        # Killed before the run's first summary.json: the folder holds no run, and must hold no
        # rows or images under final names either.
        rows = reader.read_frames(run_dir)
        images = list((run_dir / "frames").glob("[0-9]*")) if (run_dir / "frames").is_dir() else []
        return [f"no summary.json but {len(rows)} rows and {len(images)} images"] if rows or images else []
    except ValueError as error:
        return [f"summary.json cannot be read: {error}"]
    frames = reader.read_frames(run_dir)
    count = summary.get("frame_count")
    # A kill can land after the final summary.json was renamed into place (a kill at the last
    # summary write): the run is then whole, and says so.
    whole = summary.get("partial") is False and count == summary.get("frames_planned")
    if killed and summary.get("partial") is not True and not whole:
        problems.append(f"summary.json of a killed run is neither partial nor whole: partial="
                        f"{summary.get('partial')!r}, {count} of {summary.get('frames_planned')} frames")
    if count != len(frames):
        problems.append(f"summary frame_count {count} != {len(frames)} frames.csv rows read")
    numbers = [row["frame"] for row in frames]
    if numbers != list(range(first_frame, first_frame + len(numbers))):
        problems.append(f"frames read are not the first ones of the range in order: {numbers[:5]}...")
    images = reader.run_images(run_dir, summary)
    if sorted(images) != numbers:
        problems.append(f"images read {sorted(images)[:5]}... != frames read {numbers[:5]}...")
    for frame, path in images.items():
        if not reader.image_is_complete(path):
            problems.append(f"image of frame {frame} is incomplete: {path.name}")
    for path in (run_dir / "frames").glob("[0-9]*") if (run_dir / "frames").is_dir() else ():
        if not reader.image_is_complete(path):
            problems.append(f"an image under its final name is incomplete: {path.name}")
    logged = set(numbers)
    stray = {row["frame"] for row in reader.iter_selection(run_dir)} - logged
    if stray:
        problems.append(f"selection rows read of frames not in the run: {sorted(stray)[:5]}")
    try:
        files = report.build_report([reference_dir, run_dir], reference=reference_dir, out_dir=report_dir)
    except (ValueError, OSError) as error:
        problems.append(f"the report refused the folder: {error}")
    else:
        text = files.markdown.read_text(encoding="utf-8")
        if summary.get("partial") and "Partial runs" not in text:
            problems.append("the report does not say the run is partial")
    return problems


def run(kills: int, out: Path, seed: int, scene: str = "arcade", frame_count: int = 40, log=print,
        max_skip: int = 5, max_delay_s: float = 4.0) -> list:
    rng = random.Random(seed)
    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    frames = f"1-{frame_count}"
    reference = out / "reference"
    subprocess.run(_phrt() + ["render", scene, "--frames", frames, "--out", str(reference), *RENDER_ARGS[:2],
                              "--mode", "raytrace", "--images", "exr"], check=True, stdout=subprocess.DEVNULL)
    results = []
    for number in range(kills):
        moment = MOMENTS[number % len(MOMENTS)]
        overwrite = number % 4 == 3
        run_dir = results[-1].run_dir if overwrite else out / f"kill-{number:02d}"
        kill = Kill(number, moment, run_dir, overwrite)
        kill.killed = kill_once(scene, run_dir, moment, rng, frames, overwrite, max_skip=max_skip,
                                max_delay_s=max_delay_s)
        kill.problems = check_folder(run_dir, reference, 1, kill.killed, out / "report")
        try:
            from phrt.phrt_addon.runs import run_files as reader
            kill.frames = reader.read_summary(run_dir).get("frame_count") or 0
        except (FileNotFoundError, ValueError):
            pass
        results.append(kill)
        state = "killed" if kill.killed else "ended first"
        log(f"kill {number + 1}/{kills} at {moment}{' (--overwrite)' if overwrite else ''}: {state} after "
            f"{kill.frames} frames: {'; '.join(kill.problems) or 'consistent'}")
    return results


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=20)
    parser.add_argument("--out", default="out/faults")
    parser.add_argument("--seed", type=int, default=int(time.time()))
    parser.add_argument("--scene", default="arcade")
    parser.add_argument("--frames", type=int, default=40, help="frames of each replay")
    args = parser.parse_args(argv)
    print(f"faults: {args.kills} kills, seed {args.seed}", flush=True)
    results = run(args.kills, Path(args.out), args.seed, args.scene, args.frames,
                  log=lambda line: print(line, flush=True))
    bad = [kill for kill in results if kill.problems]
    killed = sum(kill.killed for kill in results)
    print(f"faults: {killed} of {len(results)} replays killed, {len(bad)} inconsistent folders")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
