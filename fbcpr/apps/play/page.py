"""The playground's web page (viser: three.js scene, GUI widgets and a websocket, all driven from Python) and the
loop that steps the body at 30 control steps a second and draws it.

The page's widgets run in viser's threads and only change the `Session` (prompt, reset, push) or the loop's
settings (pause, step, speed, follow); the loop thread steps and draws. A prompt that fails shows its message on
the page and leaves the running prompt as it was.
"""
from __future__ import annotations

import re
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from fbcpr.apps.play.body import Body
from fbcpr.apps.play.session import Prompts, Session, Source
from fbcpr.core.errors import FBCPRError
from humanoid_env.model import CONTROL_HZ

#: Seconds of reward the plot shows.
PLOT_SECONDS = 10.0
#: The text widgets and the plot are refreshed every this many control steps (the body every step).
READOUT_EVERY = 3
#: The timeline the page offers first (walk, then stand still, then walk again).
DEFAULT_TIMELINE = "move-ego-0-2:4,move-ego-0-0:3,move-ego-0-2:4"
#: The camera's place relative to the pelvis when the page opens (metres, z up).
CAMERA_OFFSET = np.array([2.0, -2.0, 0.4])


def escape_markdown(text: str) -> str:
    """`text` shown as it is in a markdown widget (a reward name's '*' would otherwise start italics)."""
    return re.sub(r"([\\`*_{}\[\]<>()#+!|~-])", r"\\\1", text)


class Playground:
    """A viser server showing one `Session`; `run` steps and draws it until stopped."""

    def __init__(self, session: Session, prompts: Prompts, tasks: list[str], goals: list[str],
                 clips: dict[str, str], host: str = "127.0.0.1", port: int = 8080) -> None:
        from fbcpr.core.extras import require

        viser = require("viser", "play", "fbcpr play")
        self.session, self.prompts, self.tasks, self.clips = session, prompts, tasks, clips
        self.server = viser.ViserServer(host=host, port=port, label="fbcpr play", verbose=False)
        self.server.gui.configure_theme(control_width="large", show_share_button=False, show_logo=False)
        self.server.scene.set_up_direction("+z")
        self.server.initial_camera.look_at = (0.0, 0.0, 0.9)
        self.server.initial_camera.position = tuple(np.array([0.0, 0.0, 0.9]) + CAMERA_OFFSET)
        self.body = Body(self.server, session.env.model)
        self.paused, self.step_once, self.speed, self.follow = False, False, 1.0, True
        self.stopped = threading.Event()
        self.rewards: deque[tuple[float, float]] = deque(maxlen=int(PLOT_SECONDS * CONTROL_HZ))
        self._build_gui(viser, goals)

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    # ----------------------------------------------------------------------------------------------- page
    def _build_gui(self, viser: Any, goals: list[str]) -> None:
        gui = self.server.gui
        self.status = gui.add_markdown(self._status_text())
        self.message = gui.add_markdown("")
        self.readout = gui.add_markdown("")
        self.plot = gui.add_uplot(
            data=(np.zeros(1), np.zeros(1)),
            series=(viser.uplot.Series(label="time (s)"),
                    viser.uplot.Series(label="reward", stroke="#2f7ed8", width=2)),
            title="reward of the current prompt", aspect=2.0,
            scales={"x": viser.uplot.Scale(time=False, auto=True), "y": viser.uplot.Scale(range=(0.0, 1.0))},
            legend=viser.uplot.Legend(show=False))
        with gui.add_folder("Reward task"):
            search = gui.add_text("Search", "", hint="Part of a task name: narrows the list below")
            task = gui.add_dropdown("Task", self.tasks, initial_value=self.session.source.label
                                    if self.session.source.label in self.tasks else self.tasks[0])
            go_reward = gui.add_button("Prompt reward")
        with gui.add_folder("Goal pose"):
            goal = gui.add_dropdown("Pose", goals)
            go_goal = gui.add_button("Reach pose")
        with gui.add_folder("Clip"):
            clip = gui.add_dropdown("Clip", list(self.clips) or ["(no clips)"])
            go_clip = gui.add_button("Track clip")
        with gui.add_folder("Timeline"):
            timeline = gui.add_text("Items", DEFAULT_TIMELINE, hint="ITEM:SECONDS,...: reward tasks, goal poses, "
                                    "clip files or built-in clips, played in turn")
            go_timeline = gui.add_button("Play timeline")
        with gui.add_folder("Body"):
            stand, fall, push = (gui.add_button(label) for label in ("Reset standing", "Reset from a fall", "Push"))
            pause, step = gui.add_checkbox("Pause", False), gui.add_button("Step")
            speed = gui.add_slider("Speed", min=0.1, max=1.0, step=0.05, initial_value=1.0,
                                   hint="Slow motion: the share of real time the simulation runs at")
            follow = gui.add_checkbox("Follow camera", True)

        @search.on_update
        def _(_: Any) -> None:
            query = search.value.strip().lower()
            matches = [t for t in self.tasks if query in t.lower()]
            task.options = matches or ["(no task matches)"]

        go_reward.on_click(lambda _: self._prompt(lambda: self.prompts.reward(task.value)))
        go_goal.on_click(lambda _: self._prompt(lambda: self.prompts.goal(goal.value)))
        go_clip.on_click(lambda _: self._prompt(lambda: self.prompts.clip(self.clips[clip.value], clip.value)))
        go_timeline.on_click(lambda _: self._prompt(lambda: self.prompts.timeline(timeline.value)))
        stand.on_click(lambda _: self.session.reset())
        fall.on_click(lambda _: self.session.reset(fallen=True))
        push.on_click(lambda _: self.session.push())
        step.on_click(lambda _: setattr(self, "step_once", True))
        pause.on_update(lambda _: setattr(self, "paused", pause.value))
        speed.on_update(lambda _: setattr(self, "speed", float(speed.value)))
        follow.on_update(lambda _: setattr(self, "follow", follow.value))

    def _prompt(self, build: Callable[[], Source]) -> None:
        """Swap the body's prompt for what `build` makes; on failure show why and keep the prompt it has."""
        try:
            source = build()
        except (FBCPRError, KeyError) as err:
            text = err.args[0] if isinstance(err, KeyError) and err.args else str(err)
            self.message.content = f"**Not changed:** {escape_markdown(text)}. The body keeps its prompt."
            return
        self.session.use(source)
        self.rewards.clear()
        self.message.content = ""

    def _status_text(self) -> str:
        return f"**z from:** {self.session.source.describe(self.session.t)}"

    # ----------------------------------------------------------------------------------------------- loop
    def tick(self) -> bool:
        """One control step unless paused (then only on a Step request), and the scene and readouts drawn;
        returns whether the body stepped."""
        stepped = not self.paused or self.step_once
        if stepped:
            self.step_once = False
            reward = self.session.step()
            self.rewards.append((self.session.steps / CONTROL_HZ, reward))
        self.draw(refresh=self.session.steps % READOUT_EVERY == 0 or not stepped)
        return stepped

    def draw(self, refresh: bool) -> None:
        """Pose the body, move the followed camera, and (with `refresh`) the texts and the plot."""
        data = self.session.env.data
        self.body.update(data)
        pelvis = np.array(data.qpos[:3])
        if self.follow:
            target = np.array([pelvis[0], pelvis[1], 0.9])
            for client in self.server.get_clients().values():
                camera = client.camera
                if camera.update_timestamp == 0.0:  # the page has not reported its camera yet
                    continue
                shift = target - np.asarray(camera.look_at)
                if np.abs(shift).max() > 1e-3:  # moving the camera moves its look-at point with it: the view holds
                    camera.position = np.asarray(camera.position) + shift
        if refresh:
            self.status.content = self._status_text()
            self.readout.content = (f"t = {self.session.steps / CONTROL_HZ:.1f} s · pelvis (x, y, z) = "
                                    f"({pelvis[0]:.2f}, {pelvis[1]:.2f}, {pelvis[2]:.2f}) m · reward "
                                    f"{self.session.reward:.3f}" + (" · paused" if self.paused else ""))
            if self.rewards:
                t, r = np.array(self.rewards).T
                self.plot.data = (t, r)

    def run(self, seconds: float | None = None, realtime: bool = True) -> float:
        """Step and draw at 30 steps per second of simulated time (times the speed) until `stop` or `seconds`
        have passed; without `realtime`, as fast as it goes. Returns control steps per wall-clock second."""
        start = time.monotonic()
        steps, due = 0, start
        while not self.stopped.is_set() and (seconds is None or time.monotonic() - start < seconds):
            steps += self.tick()
            if realtime:
                due += 1.0 / (CONTROL_HZ * self.speed)
                now = time.monotonic()
                if due < now - 1.0:  # far behind (a suspended laptop): do not race to catch up
                    due = now
                self.stopped.wait(max(0.0, due - now))
        return steps / max(time.monotonic() - start, 1e-9)

    def stop(self) -> None:
        self.stopped.set()
        self.server.stop()
