"""Screenshot of the rerun viewer showing a run, as a user sees it: headless, under Xvfb.

    python -m pipeline.tools.screenshot RUN_DIR [--out outputs/screenshot.png]
                                        [--size 1600x1000] [--colors 256]

Builds the recording as `make view` does (RUN_DIR/run.rrd), starts its own X server (Xvfb),
runs the native viewer in it (Vulkan; without a GPU Mesa's software driver, lavapipe),
captures the screen (ImageMagick's `import`) once the window has stopped changing (the
recording loaded, the start-up notices gone), writes a PNG and stops everything it started.
Linux only. Needs: apt-get install xvfb imagemagick mesa-vulkan-drivers.

Xvfb runs without its Composite extension: with it, winit picks a 32-bit (transparent)
visual, and lavapipe's frames never reach the screen of an X server without a compositing
manager (the capture is black). The screen is twice the window's height so the pointer,
which Xvfb puts in the screen's centre, is below the window and hovers nothing. The viewer
runs with its own empty config (analytics off, no saved layout, the recording's blueprint)
and its server on 127.0.0.1 and a free port, beside any viewer already open.
"""

from __future__ import annotations

import argparse
import glob
import io
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from PIL import Image

from pipeline.errors import PipelineError, existing_dir, os_error_reason
from pipeline.tools import run_tool

try:
    from pipeline.tools.viewer import build_recording, viewer_command, warn_if_incomplete
except ModuleNotFoundError as e:  # rerun-sdk, the optional viewer extra: its message
    if e.name != "rerun" or __name__ != "__main__":
        raise
    print(f"error: {e}", file=sys.stderr)
    sys.exit(2)

# Not docs/viewer.png (the README's): that one is replaced only when asked for by name.
DEFAULT_OUT = Path("outputs/screenshot.png")
MIN_COLOURS = 64  # fewer: a blank screen (a black one has 1), not the viewer
VULKAN_ICD_DIRS = ["/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d"]
MARK = "BIRLG_SCREENSHOT"  # in the environment of Xvfb and the viewer: the recording's path


def require_tools() -> None:
    """Xvfb, ImageMagick's import and a Vulkan driver, or a one-line error naming the
    package that provides the missing one."""
    for exe, package in (("Xvfb", "xvfb"), ("import", "imagemagick")):
        if shutil.which(exe) is None:
            raise PipelineError(f"{exe} not found: apt-get install {package}")
    if not any(glob.glob(f"{d}/*.json") for d in VULKAN_ICD_DIRS):
        raise PipelineError("no Vulkan driver found (the viewer renders with Vulkan; without "
                            "a GPU Mesa's lavapipe): apt-get install mesa-vulkan-drivers")


def start_xvfb(width: int, height: int, env: dict[str, str], log_path: Path,
               timeout_s: float = 20.0) -> tuple[subprocess.Popen, str]:
    """An X server on a free display number (Xvfb -displayfd), ready when this returns."""
    read_fd, write_fd = os.pipe()
    try:
        with open(log_path, "w") as log_file:
            proc = subprocess.Popen(
                ["Xvfb", "-displayfd", str(write_fd), "-screen", "0", f"{width}x{height}x24",
                 "-nolisten", "tcp", "-extension", "Composite"],
                pass_fds=(write_fd,), env=env, start_new_session=True,
                stdout=subprocess.DEVNULL, stderr=log_file)
    finally:
        os.close(write_fd)
    # Xvfb writes the display number once it accepts clients; the pipe closes if it exits.
    with os.fdopen(read_fd) as ready:
        in_time = bool(select.select([ready], [], [], timeout_s)[0])
        number = ready.readline().strip() if in_time else ""
    if not number:
        what = "exited" if in_time else f"did not start within {timeout_s:g} s"
        stop(proc)
        lines = [line.removeprefix("(EE)").strip()
                 for line in log_path.read_text(errors="replace").splitlines()]
        raise PipelineError(f"Xvfb {what}: {([ln for ln in lines if ln] or ['no output'])[-1]}")
    return proc, f":{number}"


def stop(proc: subprocess.Popen, timeout_s: float = 10.0) -> None:
    """End proc and its process group (the `rerun` wrapper runs the viewer as a child)."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        except ProcessLookupError:
            proc.wait()
    else:  # the leader is gone; children in its group may not be
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


def capture(display: str, width: int, height: int) -> Image.Image:
    """The top-left width x height of the X screen (where the viewer's window is)."""
    try:
        res = subprocess.run(["import", "-display", display, "-window", "root", "ppm:-"],
                             capture_output=True, timeout=60, check=False)
    except subprocess.TimeoutExpired:
        raise PipelineError("screen capture (import) did not finish within 60 s") from None
    if res.returncode != 0:
        err = res.stderr.decode(errors="replace").strip()
        raise PipelineError(f"screen capture failed: {(err.splitlines() or ['no output'])[-1]}")
    return Image.open(io.BytesIO(res.stdout)).convert("RGB").crop((0, 0, width, height))


def colour_count(image: Image.Image) -> int:
    colours = image.getcolors(maxcolors=1 << 24)
    return len(colours) if colours else 1 << 24


def wait_until_still(display: str, width: int, height: int, viewer: subprocess.Popen,
                     log_path: Path, settle_s: float, timeout_s: float) -> Image.Image:
    """Capture every second until the screen is not blank and has not changed for settle_s;
    the viewer dying or timeout_s passing is an error."""
    start = time.monotonic()
    last, since = None, start
    while True:
        time.sleep(1.0)
        if viewer.poll() is not None:
            lines = log_path.read_text(errors="replace").strip().splitlines()
            raise PipelineError(f"the viewer exited with status {viewer.returncode} "
                                f"({(lines or ['no output'])[-1]}); full output in {log_path}")
        image, now = capture(display, width, height), time.monotonic()
        if last is None or image.tobytes() != last.tobytes():
            last, since = image, now
        elif now - since >= settle_s and colour_count(image) >= MIN_COLOURS:
            return image
        if now - start > timeout_s:
            what = "the screen stayed blank" if colour_count(image) < MIN_COLOURS \
                else "the window kept changing"
            raise PipelineError(f"the viewer did not settle within {timeout_s:g} s ({what}); "
                                f"viewer output in {log_path}")


def screenshot(run_dir: Path, out: Path, width: int = 1600, height: int = 1000,
               settle_s: float = 8.0, timeout_s: float = 120.0, colours: int = 0) -> Path:
    """Build run_dir's recording, show it in the viewer under Xvfb, save the screen as out
    (with colours > 0, as a PNG of that many colours: a third of the size, looks the same)."""
    require_tools()
    rrd = build_recording(run_dir)
    log_path = rrd.with_suffix(".screenshot.log")
    cmd = viewer_command(rrd)
    with tempfile.TemporaryDirectory(prefix="birlg-shot-") as tmp:
        env = {**os.environ, "XDG_CONFIG_HOME": f"{tmp}/config", "XDG_DATA_HOME": f"{tmp}/data",
               "XDG_CACHE_HOME": f"{tmp}/cache", "XDG_RUNTIME_DIR": tmp,
               MARK: str(rrd)}  # marks the processes this starts (the test looks for strays)
        env.pop("WAYLAND_DISPLAY", None)
        # rerun's own command writes its config file: analytics off for this throwaway config
        res = subprocess.run([*cmd[:-1], "analytics", "disable"], env=env, check=False,
                             capture_output=True, text=True, timeout=60)
        if res.returncode != 0:
            last = (res.stderr.strip().splitlines() or ["no output"])[-1]
            raise PipelineError(f"{' '.join(cmd[:-1])} analytics disable failed: {last}")
        # twice the window's height: the pointer (centred) below it
        xvfb, display = start_xvfb(width, 2 * height, env, Path(tmp) / "xvfb.log")
        try:
            with open(log_path, "w") as log_file:
                viewer = subprocess.Popen(
                    [*cmd[:-1], "--renderer", "vulkan", "--bind", "127.0.0.1", "--port", "auto",
                     "--window-size", f"{width}x{height}", cmd[-1]],
                    env={**env, "DISPLAY": display}, start_new_session=True,
                    stdout=log_file, stderr=subprocess.STDOUT)
            try:
                image = wait_until_still(display, width, height, viewer, log_path, settle_s,
                                         timeout_s)
            finally:
                stop(viewer)
        finally:
            stop(xvfb)
    if colours:
        image = image.quantize(colours, method=Image.Quantize.FASTOCTREE,
                               dither=Image.Dither.NONE)
    out.parent.mkdir(parents=True, exist_ok=True)
    image.save(out, optimize=True)
    return out


def _size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT, e.g. 1600x1000") \
            from None
    return width, height


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pipeline.tools.screenshot",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("run_dir", type=Path, help="a run directory holding the stage artefacts")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT,
                    help=f"the PNG to write (default {DEFAULT_OUT})")
    ap.add_argument("--size", type=_size, default=(1600, 1000),
                    help="the viewer window, WIDTHxHEIGHT (default 1600x1000)")
    ap.add_argument("--settle", type=float, default=8.0, help="seconds the screen must stay "
                    "unchanged before the capture (default 8: the start-up notices last ~5 s)")
    ap.add_argument("--colors", type=int, default=0, help="write a PNG of this many colours "
                    "(at most 256; default 0: every colour captured)")
    ap.add_argument("--timeout", type=float, default=120.0,
                    help="give up after this many seconds (default 120)")
    args = ap.parse_args(argv)
    if not 0 <= args.colors <= 256:
        ap.error(f"--colors {args.colors}: a PNG palette has 1 to 256 colours (0: no palette)")
    for name in ("settle", "timeout"):
        if not getattr(args, name) > 0:
            ap.error(f"--{name} {getattr(args, name)}: seconds > 0")
    if args.out.suffix.lower() != ".png":  # said after the capture otherwise
        ap.error(f"--out {args.out}: the screenshot is a PNG; name it ....png")
    try:  # before the tools it needs: the run dir is the news
        existing_dir(args.run_dir, "run dir")
    except PipelineError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if not sys.platform.startswith("linux"):
        print("error: the screenshot runs the viewer under Xvfb, on Linux only", file=sys.stderr)
        return 2
    warn_if_incomplete(args.run_dir)
    try:
        out = screenshot(args.run_dir, args.out, *args.size, settle_s=args.settle,
                         timeout_s=args.timeout, colours=args.colors)
    except PipelineError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"error: cannot take the screenshot of {args.run_dir}: {os_error_reason(e)}",
              file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    run_tool(main)
