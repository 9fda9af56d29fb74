"""Response time of the viewer (issue 20): a slider move, server side and in a real browser.

    MUJOCO_GL=egl python benchmarks/bench_view.py [--moves 30] [--shots docs/view] [--out benchmarks/results_view.md]

* **server, compute**: the session's frame for an uncached control value (``PancakeSession.update`` etc.:
  build the sketch/command, run the model, trust signals) — what a slider move costs the model;
* **server, handler**: the whole callback (compute, draw the path figure, push the plots, the readout
  and the 3-D lines to the page), timed inside the running app with a browser connected;
* **browser, round trip**: from a key press on the slider's thumb in headless Chromium (playwright,
  Debian's ``chromium``) until the page's readout shows the new motion — input event, websocket,
  server, websocket, React render.

Moves step the slider one notch at a time (each value new, so nothing is served from the cache) and
wait for each redraw. torch runs on one thread (what ``seqmotion view`` sets by default). With
``--shots DIR`` it also writes the README's screenshots (one per panel, downscaled PNGs).
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import torch

NOTES = [
    "Notes:",
    "",
    "* The model's part of a slider move is a few milliseconds (one torch thread); the whole server callback adds",
    "  the path figure (Pillow), the uPlot data and the 3-D lines. Its maxima include one-time work: the first",
    "  plan of a panel (warm-up) and, for `latent.redraw`, building the pushing panel (rendering its 18 webcam",
    "  images) on first selection. `keep_end` (IPOPT) and the latent adjustment are not slider-speed and say so.",
    "* The browser is headless Chromium with **software** WebGL (SwiftShader) on the same two cores as the server",
    "  and whatever else runs there: it draws the 3-D view on the CPU, which is where the tail of \"pushed by the",
    "  server → shown\" comes from (the 3-D view redraws on every change of the scene). A desktop browser with a",
    "  GPU was not available to measure. 'paths in 3D' off stops updating the 3-D paths on a move; in software",
    "  WebGL the difference is within the noise of a shared machine.",
    "",
]


def cpu_name() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        return next(line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name"))
    except Exception:  # noqa: BLE001 - not Linux
        return platform.processor() or "unknown"


def stats(seconds: list[float]) -> str:
    ms = 1000 * np.asarray(seconds)
    return f"{np.median(ms):.1f} | {np.percentile(ms, 90):.1f} | {ms.max():.1f} | {len(ms)}"


def compute_times(moves: int) -> dict[str, list[float]]:
    import seqmotion as sm
    from seqmotion.view.sessions import (
        LatentSession,
        PancakeControls,
        PancakeSession,
        SlidingControls,
        SlidingSession,
    )

    out: dict[str, list[float]] = {}
    pancake = PancakeSession(sm.load_pretrained("pancake"))
    pancake.update(PancakeControls())  # warm-up
    out["pancake: end y slider (K = 500)"] = [
        pancake.update(PancakeControls(end_y=round(0.2 - 0.005 * (i + 1), 3))).seconds for i in range(moves)]
    out["pancake: duration slider (K = 510…)"] = [
        pancake.update(PancakeControls(length=510 + 10 * i)).seconds for i in range(min(moves, 30))]
    out["pancake: keep_end on (IPOPT polish)"] = [
        pancake.update(PancakeControls(end_y=round(0.2 - 0.01 * i, 3), keep_end=True)).seconds for i in range(5)]
    start = time.perf_counter()
    try:
        pancake.adjust(PancakeControls(), (0.1, 0.0, np.pi), updates=6)
        out["pancake: latent adjustment, 6 LM updates"] = [time.perf_counter() - start]
    except RuntimeError as exc:  # say so in the output rather than lose the other numbers
        print(f"latent adjustment failed: {exc}")
    sliding = SlidingSession(sm.load_pretrained("sliding"))
    base = sliding.defaults()
    sliding.update(base)
    out["sliding: μ slider (line, K = 500)"] = [
        sliding.update(SlidingControls(mu=round(base.mu - 0.01 * (i + 1), 2), mu_dyn=0.3)).seconds
        for i in range(moves)]
    latent = LatentSession(sm.load_pretrained("pancake"))
    latent.update((0.0,) * 5)
    out["latent: PC1 slider (pancake)"] = [latent.update((0.1 * (i + 1), 0, 0, 0, 0)).seconds for i in range(moves)]
    return out


def browser_times(moves: int, shots: Path | None) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    from playwright.sync_api import sync_playwright

    from seqmotion.view.app import ViewerApp

    chromium = os.environ.get("SEQMOTION_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    app = ViewerApp("pancake", port=0, out="/tmp/seqmotion-view-bench")
    rounds: dict[str, list[float]] = {}
    legs: dict[str, list[float]] = {}
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium, args=[
                "--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"])
            page = browser.new_page(viewport={"width": 1280, "height": 1700})
            page.goto(app.url)
            page.locator("p", has_text="motion, K =").first.wait_for(timeout=60_000)
            app.wait_idle()
            page.wait_for_timeout(1000)
            for button in page.locator(".mantine-Notification-closeButton").all():
                button.click(force=True)
            app.timings.clear()

            def row(label: str, on=None):  # noqa: ANN001, ANN202
                return (on or page).locator(f'label:text-is("{label}")').first.locator(
                    "xpath=ancestor::div[contains(@class, 'mantine-Flex-root')][1]")

            def move(name: str, label: str, marker: str, key: str, n: int, panel: str) -> None:
                readout = page.locator("p", has_text=marker).first
                thumb = row(label).locator('[role="slider"]')
                thumb.focus()
                times = []
                for _ in range(n):
                    before = readout.inner_text()
                    handle = readout.element_handle()
                    start = time.perf_counter()
                    page.keyboard.press(key)
                    page.wait_for_function("([el, text]) => el.innerText !== text", arg=[handle, before],
                                           polling=5, timeout=30_000)
                    shown = time.perf_counter()
                    times.append(shown - start)
                    app.wait_idle()
                    legs.setdefault(f"{name} — of which key press → event at the server", []).append(
                        app.marks[f"{panel}.event"] - start)
                    legs.setdefault(f"{name} — of which pushed by the server → shown", []).append(
                        shown - app.marks[f"{panel}.pushed"])
                rounds[name] = times

            move("pancake: end y slider (K = 500)", "end y [m]", "motion, K =", "ArrowLeft", moves, "pancake")
            app.paths_box.value = False  # the page's "paths in 3D" off: the 3-D view no longer redraws on a move
            app.wait_idle()
            move("pancake: end y slider, 'paths in 3D' off", "end y [m]", "motion, K =", "ArrowRight", moves,
                 "pancake")
            app.paths_box.value = True
            app.wait_idle()
            page.get_by_role("tab", name="Sliding").click(force=True)
            page.locator("p", has_text="for a line command").first.wait_for(timeout=30_000)
            move("sliding: μ slider (line, K = 500)", "μ (static)", "for a line command", "ArrowLeft", moves, "sliding")
            page.get_by_role("tab", name="Latent space").click(force=True)
            page.locator("p", has_text="decoded z at").first.wait_for(timeout=60_000)
            app.wait_idle()
            move("latent: PC1 slider (pancake)", "PC1 [σ]", "decoded z at", "ArrowRight", moves, "latent")
            page.close()
            handlers = {k: v for k, v in app.timings.items()}
            if shots:  # a fresh page, tall enough for a whole panel; the controls keep their values (server side)
                tall = browser.new_page(viewport={"width": 1280, "height": 2300})
                tall.goto(app.url)
                tall.locator("p", has_text="motion, K =").first.wait_for(timeout=60_000)
                tall.wait_for_timeout(1500)
                for button in tall.locator(".mantine-Notification-closeButton").all():
                    button.click(force=True)

                def shot(name: str) -> None:
                    app.wait_idle()
                    tall.wait_for_timeout(1500)
                    tall.screenshot(path=str(shots / name))

                pancake = app.panels["pancake"]
                pancake.keep_end.value = True  # the exact polish: the motion ends at the sketch's end
                pancake.request()
                tall.locator("p", has_text="keep_end motion").first.wait_for(timeout=60_000)
                shot("pancake.png")
                tall.get_by_role("tab", name="Sliding").click(force=True)
                row("shape", tall).locator("input").first.click(force=True)
                tall.get_by_role("option", name="spline").click()
                tall.locator("p", has_text="for a spline command").first.wait_for(timeout=30_000)
                shot("sliding.png")
                tall.get_by_role("tab", name="Latent space").click(force=True)
                shot("latent.png")
                row("model", tall).locator("input").first.click(force=True)
                tall.get_by_role("option", name="pushing").click()
                tall.locator("p", has_text="pushing model").first.wait_for(timeout=120_000)
                shot("latent-pushing.png")
            browser.close()
        rounds.update(legs)
    finally:
        app.stop()
    return rounds, handlers


def shrink(path: Path, width: int = 900) -> None:
    """Downscale a screenshot and reduce it to a 128-colour palette: small enough to commit."""
    from PIL import Image

    img = Image.open(path).convert("RGB")
    img = img.resize((width, round(img.height * width / img.width)), Image.LANCZOS)
    img.quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--moves", type=int, default=30, help="slider moves per measurement (0: screenshots only)")
    parser.add_argument("--shots", type=Path, help="write the README's screenshots here")
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("results_view.md"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    compute = compute_times(args.moves) if args.moves else {}
    if args.shots:
        args.shots.mkdir(parents=True, exist_ok=True)
    rounds, handlers = browser_times(args.moves, args.shots)
    load_after = os.getloadavg()
    if args.shots:
        for png in sorted(args.shots.glob("*.png")):
            shrink(png)
    if not args.moves:
        return
    lines = [
        "# Viewer response time (issue 20)",
        "",
        "`MUJOCO_GL=egl python benchmarks/bench_view.py` — a slider move in `seqmotion view`, one notch at a time,",
        "each value new (no cache hit). torch on one thread (the viewer's default). Milliseconds.",
        "",
        f"Machine: {cpu_name()}, {os.cpu_count()} cores; torch {torch.__version__}; Chromium headless "
        f"(software WebGL); load average {load_before[0]:.2f} before, {load_after[0]:.2f} after "
        "(other work shared the machine).",
        "",
        "## Server side: computing the frame (the model's part)",
        "",
        "| slider | median | p90 | max | moves |",
        "|---|---|---|---|---|",
        *[f"| {name} | {stats(values)} |" for name, values in compute.items()],
        "",
        "## Server side: the whole callback (compute + figures + push to the page), browser connected",
        "",
        "| handler | median | p90 | max | calls |",
        "|---|---|---|---|---|",
        *[f"| {name} | {stats(values)} |" for name, values in sorted(handlers.items())],
        "",
        "## In the browser: key press on the slider → the page shows the new motion",
        "",
        "| slider | median | p90 | max | moves |",
        "|---|---|---|---|---|",
        *[f"| {name} | {stats(values)} |" for name, values in sorted(rounds.items())],
        "",
        *NOTES,
    ]
    args.out.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
