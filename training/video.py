"""Videos of a policy in the manipulation scene (``tasks/manipulation/scene.xml``).

``record_policy(env, policy, "DIR/new_skill", key=...)`` runs one episode of ``policy`` (a pure
``policy(obs, key) -> action``, e.g. ``make_policy(params, "new_skill")``) on any backend of the
manipulation domain and writes ``DIR/new_skill.mp4`` (H.264 through imageio-ffmpeg, the
``[video]`` extra), or ``DIR/new_skill.gif`` (Pillow) where ffmpeg is not available.

Frames come from the observations alone, so every backend renders the same way: the observation
holds the gripper joints (pinch x, y, z, wrist yaw), the finger aperture and each cube's pose,
which ``qpos_from_observations`` writes into the scene's qpos (fingers at half the aperture each,
the scene's convention); ``mj_forward`` places the bodies and MuJoCo's renderer draws the
``front`` camera. For the kinematic domain this is its exact state; for the physics backends
the two fingers are drawn symmetric.

Rendering is headless and runs in a child process (``python -m training.video _render ...``)
with ``MUJOCO_GL`` set before MuJoCo is imported there: ``egl`` first, then ``osmesa`` (or the
one ``$MUJOCO_GL`` names first). The training process never creates a GL context.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from typing import Optional, Sequence

import numpy as np

DEFAULT_SIZE = (480, 360)  # width, height (the scene's offscreen buffer is 640 x 480)
GIF_MAX_FPS = 10  # GIFs keep every n-th frame: smaller files
BACKENDS = ("egl", "osmesa")
EXIT_GL, EXIT_ENCODE = 3, 4  # worker exit codes: no GL context / cannot encode


class VideoError(RuntimeError):
    """A video could not be written. ``gl`` is True when no headless GL backend worked."""

    def __init__(self, message: str, gl: bool = False):
        super().__init__(message)
        self.gl = gl


def qpos_from_observations(obs) -> np.ndarray:
    """Scene qpos [..., NQ] from observations [..., OBS_SIZE] (layout of ``tasks.manipulation.layout``):
    slide x, y, z, yaw, finger_left, finger_right (half the aperture each), then each cube's
    free joint (position, quaternion w x y z)."""
    from tasks.manipulation import layout as L
    from tasks.manipulation import physics_np as P

    obs = np.asarray(obs, np.float64)
    qpos = np.zeros(obs.shape[:-1] + (P.NQ,))
    qpos[..., 0:4] = obs[..., L.OBS_SLICES["joint_pos"]]
    half = 0.5 * np.clip(obs[..., L.FINGER], L.APERTURE_CLOSED, L.APERTURE_OPEN)
    qpos[..., 4] = half
    qpos[..., 5] = half
    for c, name in enumerate(L.CUBE_NAMES):
        start = P.CUBE_QPOS[c]
        qpos[..., start:start + 3] = obs[..., L.cube_pos(name)]
        qpos[..., start + 3:start + 7] = obs[..., L.cube_quat(name)]
    return qpos


def rollout_observations(env, policy, key, episode_length: Optional[int] = None) -> np.ndarray:
    """Observations [T + 1, O] of one episode of ``policy`` on ``env`` (Brax API), reset included."""
    import jax

    length = int(episode_length or getattr(env, "episode_length", 600))

    @jax.jit
    def run(key):
        k_reset, k_act = jax.random.split(key)
        state = jax.vmap(env.reset)(k_reset[None])  # a batch of one: every backend steps batches

        def body(state, k):
            action = jax.vmap(policy)(state.obs, k[None])
            state = jax.vmap(env.step)(state, action)
            return state, state.obs[0]

        first = state.obs[0]
        _, obs = jax.lax.scan(body, state, jax.random.split(k_act, length))
        return first, obs

    first, obs = run(key)
    return np.concatenate([np.asarray(first)[None], np.asarray(obs)], axis=0)


def _backends() -> list[str]:
    first = os.environ.get("MUJOCO_GL", "").strip().lower()
    return ([first] if first in BACKENDS else []) + [b for b in BACKENDS if b != first]


def write_video(qpos, path_stem: str, *, fps: float = 20.0, size: Sequence[int] = DEFAULT_SIZE,
                camera: str = "front", fmt: str = "auto", scene: Optional[str] = None,
                backends: Optional[Sequence[str]] = None, timeout: float = 900.0) -> str:
    """Render the scene at each qpos [T, NQ] and write ``path_stem`` + ``.mp4`` (``fmt`` "auto":
    if ffmpeg is available, else ``.gif``; or "mp4" / "gif"). Returns the path written."""
    if fmt not in ("auto", "mp4", "gif"):
        raise ValueError(f"fmt must be 'auto', 'mp4' or 'gif', got {fmt!r}")
    qpos = np.asarray(qpos, np.float64)
    if qpos.ndim != 2 or len(qpos) == 0:
        raise ValueError(f"qpos must be [T >= 1, NQ], got shape {qpos.shape}")
    if scene is None:
        from tasks.manipulation.physics_np import SCENE_PATH as scene
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    errors = []
    with tempfile.TemporaryDirectory(prefix="ps_video_") as tmp:
        src = os.path.join(tmp, "qpos.npy")
        np.save(src, qpos)
        for backend in backends or _backends():
            env = dict(os.environ, MUJOCO_GL=backend, PYOPENGL_PLATFORM=backend,
                       PYTHONPATH=os.pathsep.join([root] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
            cmd = [sys.executable, "-m", "training.video", "_render", src, path_stem, "--fps", str(fps),
                   "--size", str(int(size[0])), str(int(size[1])), "--camera", camera, "--fmt", fmt, "--scene", scene]
            try:
                proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
            except subprocess.TimeoutExpired:
                errors.append(f"{backend}: timed out after {timeout:.0f} s")
                continue
            if proc.returncode == 0:
                return proc.stdout.strip().splitlines()[-1]
            last = (proc.stderr.strip().splitlines() or [f"exit code {proc.returncode}"])[-1]
            if proc.returncode == EXIT_ENCODE:
                raise VideoError(f"cannot encode the video: {last}")
            errors.append(f"{backend}: {last}")
    raise VideoError("no headless OpenGL backend works (" + "; ".join(errors) + ")", gl=True)


def record_policy(env, policy, path_stem: str, *, key, episode_length: Optional[int] = None, **kwargs) -> str:
    """One episode of ``policy`` on ``env``, written as a video (``write_video``); returns its path."""
    obs = rollout_observations(env, policy, key, episode_length)
    fps = 1.0 / float(getattr(env, "dt", 0.05) or 0.05)
    return write_video(qpos_from_observations(obs), path_stem, fps=kwargs.pop("fps", fps), **kwargs)


# ----------------------------------------------------------------------------- child process

def ffmpeg_available() -> bool:
    try:
        import imageio.v2  # noqa: F401
        import imageio_ffmpeg

        return os.path.exists(imageio_ffmpeg.get_ffmpeg_exe())
    except Exception:  # not installed, or no binary for this platform
        return False


def _render(argv):
    """``python -m training.video _render QPOS.npy STEM --fps F --size W H --camera C --fmt F --scene XML``:
    render and encode; print the path written. MUJOCO_GL is set by the parent."""
    import argparse

    p = argparse.ArgumentParser()
    p.add_argument("src")
    p.add_argument("stem")
    p.add_argument("--fps", type=float, default=20.0)
    p.add_argument("--size", type=int, nargs=2, default=list(DEFAULT_SIZE))
    p.add_argument("--camera", default="front")
    p.add_argument("--fmt", default="auto")
    p.add_argument("--scene", required=True)
    a = p.parse_args(argv)
    qpos = np.load(a.src)
    fmt = a.fmt
    if fmt == "auto":
        fmt = "mp4" if ffmpeg_available() else "gif"
    elif fmt == "mp4" and not ffmpeg_available():
        print("mp4 needs imageio and imageio-ffmpeg: pip install 'parallel-skills[video]'", file=sys.stderr)
        return EXIT_ENCODE

    import mujoco

    model = mujoco.MjModel.from_xml_path(a.scene)
    data = mujoco.MjData(model)

    def frame(q):
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        renderer.update_scene(data, camera=a.camera)
        return renderer.render()

    try:
        renderer = mujoco.Renderer(model, height=a.size[1], width=a.size[0])
        first = frame(qpos[0])
    except Exception as e:  # no GL context (driver, library or display missing)
        text = str(e).strip()
        print(f"{type(e).__name__}: {text.splitlines()[-1] if text else ''}", file=sys.stderr)
        return EXIT_GL

    def frames(stride=1):
        yield first
        for q in qpos[stride::stride]:
            yield frame(q)

    path = f"{a.stem}.{fmt}"
    tmp = f"{a.stem}.tmp-{os.getpid()}.{fmt}"
    try:
        if fmt == "mp4":
            import imageio.v2 as imageio

            with imageio.get_writer(tmp, fps=a.fps, codec="libx264", quality=7, macro_block_size=8,
                                    ffmpeg_log_level="error") as w:
                for f in frames():
                    w.append_data(f)
        else:
            from PIL import Image

            stride = max(1, int(round(a.fps / GIF_MAX_FPS)))
            images = [Image.fromarray(f) for f in frames(stride)]
            images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                           duration=int(round(1000 * stride / a.fps)), loop=0)
        os.replace(tmp, path)
    except Exception as e:
        print(f"{type(e).__name__}: {e}", file=sys.stderr)
        return EXIT_ENCODE
    finally:
        renderer.close()
        if os.path.exists(tmp):
            os.remove(tmp)
    print(path)
    return 0


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "_render":
        sys.exit(_render(sys.argv[2:]))
    print("usage: training.video is a library (record_policy, write_video); training.run --video uses it",
          file=sys.stderr)
    sys.exit(2)
