"""Record a `bavo-eval` rollout as it runs, for `bavo-eval --rerun DIR`.

Everything comes from what the rollout already has at each step (the observation, `info` and the agent's
action and predicted chunk); nothing is simulated again. The frames are those of a dataset episode
(observation o_t paired with the action sent after it) plus the final observation, with action NaN.
"""

from __future__ import annotations

import numpy as np

from lerobot_bavo.viz.episode import EpisodeData, intrinsics, to_base_frame


class RolloutRecorder:
    """Collects one episode's frames from `obs` / `info` and turns them into `EpisodeData`.

    Args:
        env: the `BavoEnv` being rolled out (read for its observation settings and, for the predicted chunks'
            gripper paths, its model: forward kinematics of the predicted joint targets on a separate MjData).
        name: the recording's name.
    """

    def __init__(self, env, name: str = "episode"):
        s = env.obs_settings
        self.env = env
        self.name = name
        self.point_frame = s.point_frame
        self.K = intrinsics(s.fovy, s.image_height, s.image_width)
        self.image_size = (s.image_height, s.image_width)
        self.fps = float(env.metadata.get("render_fps", 25))
        self.rows: dict[str, list] = {
            k: []
            for k in (
                "cloud",
                "pose",
                "rgb",
                "progress",
                "milestones",
                "visibility",
                "event",
                "event_start",
                "occluder",
                "target",
                "action",
            )
        }
        self.chunks: dict[int, np.ndarray] = {}
        self._kin = None

    def add(self, obs: dict, info: dict, action=None, chunk=None) -> None:
        """One frame: the observation and its `info`, the action sent after it (None for the last frame) and
        the (k, 21) chunk the policy predicted at this frame, if it predicted one."""
        k = len(self.rows["cloud"])
        pose = np.asarray(info["camera_pose"], dtype=np.float64)
        cloud = np.asarray(obs["point_cloud"], dtype=np.float32).copy()
        if self.point_frame == "camera":
            cloud[:, :3] = to_base_frame(cloud[:, :3].astype(np.float64), pose)
        r = self.rows
        r["cloud"].append(cloud)
        r["pose"].append(pose)
        r["rgb"].append(np.asarray(obs["pixels"]["active"], dtype=np.uint8))
        r["progress"].append(int(info["progress"]))
        flags = info.get("milestones", {})
        r["milestones"].append([bool(flags.get(f"m{i}", False)) for i in range(1, 6)])
        occ = info.get("occlusion")
        if occ is None:
            r["visibility"].append(-1.0)
            r["event"].append(-1)
            r["event_start"].append(False)
            r["occluder"].append(np.zeros(7))
            r["target"].append(None)
        else:
            vis = occ.get("visibility")
            r["visibility"].append(-1.0 if vis is None else float(vis))
            r["event"].append(int(occ["event"]["index"]))
            r["event_start"].append(bool(occ["event_started"]))
            r["occluder"].append(
                np.concatenate([occ["event"]["occluder_pos"], occ["event"]["occluder_quat"]])
            )
            r["target"].append(occ["target"])
        r["action"].append(np.full(21, np.nan) if action is None else np.asarray(action, dtype=np.float64))
        if chunk is not None:
            self.chunks[k] = np.asarray(chunk, dtype=np.float64)

    def _chunk_paths(self, chunk: np.ndarray) -> dict[str, np.ndarray]:
        """Gripper centres (and the camera) along a predicted chunk of joint targets (forward kinematics)."""
        from lerobot_bavo.sim import constants as C
        from lerobot_bavo.sim.kinematics import make_arm_kinematics

        if self._kin is None:
            self._kin = make_arm_kinematics(self.env.model)
        n = len(C.MANIPULATOR_JOINTS)
        slices = {"left": slice(0, n), "right": slice(n + 1, 2 * n + 1), "camera": slice(2 * n + 2, None)}
        return {arm: np.stack([self._kin[arm].fk(q[sl])[0] for q in chunk]) for arm, sl in slices.items()}

    def episode(self) -> EpisodeData:
        r = self.rows
        T = len(r["cloud"])
        frames = np.arange(T, dtype=np.int64)
        return EpisodeData(
            frame_index=frames,
            timestamp=frames / self.fps,
            point_cloud=np.stack(r["cloud"]),
            camera_pose=np.stack(r["pose"]),
            K=self.K,
            image_size=self.image_size,
            rgb=np.stack(r["rgb"]),
            progress=np.asarray(r["progress"], dtype=np.int64),
            milestones=np.asarray(r["milestones"], dtype=bool),
            visibility=np.asarray(r["visibility"], dtype=np.float32),
            occlusion_event=np.asarray(r["event"], dtype=np.int64),
            event_start=np.asarray(r["event_start"], dtype=bool),
            occluder_pose=np.stack(r["occluder"]).astype(np.float32),
            occlusion_target=list(r["target"]),
            action=np.stack(r["action"]),
            action_chunk=dict(self.chunks),
            chunk_paths={k: self._chunk_paths(c) for k, c in self.chunks.items()},
            name=self.name,
            meta={"source": "bavo-eval", "fps": self.fps, "task": self.env.task.name,
                  "condition": self.env.condition, "point_frame": self.point_frame},
        )

    def save(self, path) -> None:
        from lerobot_bavo.viz.log import write_rrd

        write_rrd(self.episode(), path)
