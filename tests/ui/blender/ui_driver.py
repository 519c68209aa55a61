"""Drives a real Blender window from a test script (Blender's own Python, no pytest).

A test script builds a list of steps and calls `run_steps(steps)`. Blender then starts its
event loop; a timer (bpy.app.timers) runs the steps one by one. A step is a function taking
the `UI`; when it is a generator, each value it yields is a number of seconds to wait (the
event loop runs meanwhile: modal operators, playback, redraws, the training backend's
progress). Operators run with a window context (`UI.op`), as a click on a button would run
them. A failing step writes a screenshot named after it, and every step's time, result and
screenshots go to `$ARCHHEAD_UI_OUT/result.json`, which the pytest wrapper reads; then
Blender quits.
"""

from __future__ import annotations

import contextlib
import json
import os
import struct
import sys
import time
import traceback
import zlib
from pathlib import Path

import bpy

OUT = Path(os.environ.get("ARCHHEAD_UI_OUT", "/tmp/archhead_ui"))
# Every wait is on what it needs (an object, a frame reached, a status line, a file) and
# gives up only after SAFETY times the seconds it takes on a quiet machine: the suite passes
# with other jobs loading every core, and a real failure still ends. A step has no wall-clock
# limit of its own unless $ARCHHEAD_UI_STEP_TIMEOUT sets one.
SAFETY = float(os.environ.get("ARCHHEAD_UI_SAFETY", "10"))
STEP_TIMEOUT = float(os.environ.get("ARCHHEAD_UI_STEP_TIMEOUT", "inf"))


def script_args() -> list[str]:
    return sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []


# Xvfb started with `-fbdir /tmp` keeps its screen in this file (XWD format): the pixels a
# user would see. Blender's own screenshot operators read the GL front buffer, which Mesa's
# software renderer under Xvfb returns black.
XVFB_SCREEN = Path("/tmp/Xvfb_screen0")


def screen_pixels(crop=None):
    """The Xvfb screen as (H, W, 3) uint8 RGB; `crop` = (x, y, w, h) in Blender's window
    coordinates (origin bottom left; the window fills the screen from its top left)."""
    import numpy as np

    data = XVFB_SCREEN.read_bytes()
    header = struct.unpack(">25I", data[:100])
    size, width, height, bits, line = header[0], header[4], header[5], header[11], header[12]
    check(bits == 32, f"Xvfb screen with {bits} bits per pixel")
    offset = size + header[19] * 12  # header, then the colour map
    pixels = np.frombuffer(data, np.uint8, line * height, offset).reshape(height, line // 4, 4)
    rgb = pixels[:, :width, 2::-1]  # BGRX, least significant byte first
    if crop is not None:
        x, y, w, h = crop
        window = bpy.context.window_manager.windows[0]
        top = window.height - (y + h)
        rgb = rgb[top : top + h, x : x + w]
    return np.ascontiguousarray(rgb)


def write_png(path: Path, rgb) -> None:
    """An 8-bit RGB PNG (Blender's Python has no Pillow)."""
    height, width, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[row].tobytes() for row in range(height))

    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = struct.pack(">I", zlib.crc32(kind + body))
        return struct.pack(">I", len(body)) + kind + body + crc

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 6))
    path.write_bytes(png + chunk(b"IEND", b""))


class StepFailure(AssertionError):
    pass


def check(condition, message: str) -> None:
    """assert that survives -O and says what was expected."""
    if not condition:
        raise StepFailure(message)


class UI:
    """The window, its areas and what a step needs to act on them."""

    def __init__(self):
        self.shots: list[str] = []
        self.data: dict = {}  # what steps hand each other and report
        self.step = ""

    # -- where -------------------------------------------------------------------------------
    @property
    def window(self):
        return bpy.context.window_manager.windows[0]

    def area(self, kind: str = "VIEW_3D", window=None):
        window = window or self.window
        areas = [a for a in window.screen.areas if a.type == kind]
        check(areas, f"no {kind} area in the window")
        return max(areas, key=lambda a: a.width * a.height)

    def region(self, area, kind: str = "WINDOW"):
        return next(r for r in area.regions if r.type == kind)

    def view3d(self):
        area = self.area("VIEW_3D")
        return area, area.spaces.active

    @contextlib.contextmanager
    def context(self, area_type: str | None = "VIEW_3D", window=None, region_type="WINDOW"):
        """A context as if the pointer were over `area_type` in the window."""
        window = window or self.window
        kwargs = {"window": window}
        if area_type:
            area = self.area(area_type, window)
            kwargs.update(area=area, region=self.region(area, region_type))
        with bpy.context.temp_override(**kwargs):
            yield bpy.context

    # -- acting --------------------------------------------------------------------------------
    def op(
        self,
        idname: str,
        invoke: bool = False,
        area_type="VIEW_3D",
        window=None,
        undo: bool = False,
        **props,
    ):
        """Run an operator the way a button would (INVOKE_DEFAULT with `invoke`; `undo`
        pushes its undo step, as a button or a dialog's OK does)."""
        module, name = idname.split(".")
        operator = getattr(getattr(bpy.ops, module), name)
        with self.context(area_type, window):
            check(operator.poll(), f"{idname} is not available here (poll failed)")
            return operator("INVOKE_DEFAULT" if invoke else "EXEC_DEFAULT", undo, **props)

    def redraw(self) -> None:
        """Draw the window now (what a screenshot then shows is current)."""
        for area in self.window.screen.areas:
            area.tag_redraw()
        with self.context(None):
            bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=1)

    def screenshot(self, name: str, area_type: str | None = None, window=None) -> Path:
        """What the screen shows (or one area of it) as OUT/NN_name.png."""
        path = OUT / f"{len(self.shots) + 1:02d}_{name}.png"
        self.redraw()
        crop = None
        if area_type:
            area = self.area(area_type, window)
            crop = (area.x, area.y, area.width, area.height)
        if XVFB_SCREEN.exists():
            write_png(path, screen_pixels(crop))
        else:  # a display without -fbdir: Blender's own (black under Mesa's llvmpipe)
            with self.context(area_type, window):
                op = bpy.ops.screen.screenshot_area if area_type else bpy.ops.screen.screenshot
                op(filepath=str(path), check_existing=False)
        self.shots.append(path.name)
        return path

    def key(self, key: str, ctrl=False, shift=False, alt=False, window=None, area=None) -> None:
        """Type a key with the pointer over the middle of `area` (default: the 3D view;
        Blender runs with --enable-event-simulate: these are window events, keymaps and
        modal handlers included)."""
        window = window or self.window
        area = area or self.area("VIEW_3D", window)
        x, y = area.x + area.width // 2, area.y + area.height // 2
        window.event_simulate(type="MOUSEMOVE", value="NOTHING", x=x, y=y)
        mods = {"ctrl": ctrl, "shift": shift, "alt": alt}
        window.event_simulate(type=key, value="PRESS", x=x, y=y, **mods)
        window.event_simulate(type=key, value="RELEASE", x=x, y=y, **mods)

    def click(self, x: int, y: int, window=None) -> None:
        """A left click at window coordinates (x, y) (origin bottom left)."""
        window = window or self.window
        window.event_simulate(type="MOUSEMOVE", value="NOTHING", x=x, y=y)
        window.event_simulate(type="LEFTMOUSE", value="PRESS", x=x, y=y)
        window.event_simulate(type="LEFTMOUSE", value="RELEASE", x=x, y=y)

    def show_sidebar(self, category: str = "ArchHead"):
        """Generator: opens the 3D view's sidebar (N) and clicks down its tab strip until
        `category` is the active tab (Python cannot set it: read-only)."""
        area, space = self.view3d()
        space.show_region_ui = True
        self.redraw()
        yield 0.2
        region = self.region(area, "UI")
        x = region.x + region.width - 6  # the tabs run down the sidebar's right edge
        for offset in range(10, region.height, 12):
            if region.active_panel_category == category:
                return
            self.click(x, region.y + region.height - offset)
            yield 0.15
        check(region.active_panel_category == category, f"no {category} tab in the sidebar")

    def frame_selected(self) -> None:
        with self.context("VIEW_3D"):
            bpy.ops.view3d.view_selected()

    def wait_until(self, condition, quiet: float, what: str, poll: float = 0.1):
        """Generator: yields until condition() is true. `quiet`: about how many seconds it
        takes on a quiet machine; only after SAFETY times that does the wait fail."""
        start, limit = time.monotonic(), quiet * SAFETY
        while not condition():
            waited = time.monotonic() - start
            check(
                waited < limit,
                f"not done after {waited:.0f} s ({SAFETY:g} x the {quiet:g} s it takes on a "
                f"quiet machine): {what}",
            )
            yield poll


def run_steps(steps, quit_at_end: bool = True) -> None:
    """Run (name, function) steps from a timer once the window is up; write result.json;
    quit Blender. Returns at once: the steps run in Blender's event loop."""
    OUT.mkdir(parents=True, exist_ok=True)
    ui = UI()
    result = {"steps": [], "status": "running", "blender": bpy.app.version_string}
    state = {"index": 0, "gen": None, "start": None}
    started = time.monotonic()

    def write():
        result["shots"] = ui.shots
        result["data"] = ui.data
        result["seconds"] = round(time.monotonic() - started, 2)
        (OUT / "result.json").write_text(json.dumps(result, indent=1, default=str))

    def end():
        write()
        if quit_at_end:
            with ui.context(None):
                bpy.ops.wm.quit_blender()
        return None

    def finish_step(name):
        result["steps"].append(
            {"name": name, "seconds": round(time.monotonic() - state["start"], 2), "ok": True}
        )
        print(f"ui step ok: {name} ({result['steps'][-1]['seconds']} s)", flush=True)
        state["index"] += 1
        state["gen"] = None
        write()

    def tick():
        if state["index"] >= len(steps):
            result["status"] = "passed"
            return end()
        name, function = steps[state["index"]]
        ui.step = name
        try:
            if state["gen"] is None:
                state["start"] = time.monotonic()
                print(f"ui step: {name}", flush=True)
                value = function(ui)
                if hasattr(value, "__next__"):
                    state["gen"] = value
                else:
                    finish_step(name)
                    return 0.05
            check(
                time.monotonic() - state["start"] < STEP_TIMEOUT,
                f"step took longer than {STEP_TIMEOUT} s",
            )
            try:
                delay = next(state["gen"])
            except StopIteration:
                finish_step(name)
                return 0.05
            return max(float(delay or 0.05), 0.01)
        except Exception as exc:  # noqa: BLE001 - every failure is reported with its step
            detail = traceback.format_exc()
            print(f"ui step FAILED: {name}\n{detail}", flush=True)
            shot = None
            try:
                shot = ui.screenshot(f"FAILED_{name}").name
            except Exception as shot_exc:  # noqa: BLE001
                detail += f"\n(screenshot failed: {shot_exc})"
            result["steps"].append(
                {
                    "name": name,
                    "ok": False,
                    "error": f"{type(exc).__name__}: {exc}",
                    "traceback": detail,
                    "screenshot": shot,
                }
            )
            result["status"] = "failed"
            result["failed_step"] = name
            return end()

    bpy.app.timers.register(tick, first_interval=1.0)
