"""Between a Gymnasium env's action representation and the simulator's ``joint_pos`` commands.

The simulator takes ``joint_pos`` (arm joint targets in rad + gripper closedness). Any other
representation is executed exactly as ``demo eval`` executes a policy trained on it
(:class:`demo.convert.adapter.ActionAdapter`: delta actions compose onto the last *command*, which
starts from the measured state at reset; EE poses become joint targets by IK warm-started from the
measured joints). The reverse direction, :meth:`ActionCodec.encode`, turns the expert's ``joint_pos``
command into the representation the way ``demo convert`` does (FK of the joint targets, deltas taken
against the adapter's last command), so an expert action executed through :meth:`ActionCodec.command`
commands the expert's pose.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from demo.convert import representations as reps
from demo.convert.adapter import ActionAdapter
from demo.convert.representations import ActionFormat, Anchor, JointTrack, PoseTrack


class ActionCodec:
    """Actions of ``fmt`` for the simulator env ``sim``; call :meth:`reset` after every ``sim.reset``."""

    def __init__(self, fmt: ActionFormat, sim: Any):
        self.fmt = fmt
        self.adapter = None if fmt.name == "joint_pos" else ActionAdapter(fmt, sim)

    def reset(self, sim: Any) -> None:
        """Anchor delta actions on the measured state of ``sim``."""
        if self.adapter is not None:
            self.adapter.reset(sim)

    def command(self, action: np.ndarray) -> np.ndarray:
        """The ``joint_pos`` command (float64) executing ``action``; a DemoError for a wrong shape or a
        non-finite value."""
        a = reps.check_actions(np.reshape(action, (1, -1)), self.fmt, "action")[0]
        return a if self.adapter is None else self.adapter(a)

    def encode(self, command: np.ndarray) -> np.ndarray:
        """A ``joint_pos`` command (arm targets + gripper) as a float32 action of the format."""
        c = np.asarray(command, dtype=np.float64)
        ad = self.adapter
        if ad is None:
            return c.astype(np.float32)
        gripper = c[-1:]
        if self.fmt.rep.space == "joint":
            track: JointTrack | PoseTrack = JointTrack(c[None, :-1], gripper)
            anchor = Anchor(q=ad.q_cmd[None])
        else:
            pos, rot = ad.kin.fk(c[None, :-1])
            track, anchor = PoseTrack(pos, rot, gripper), Anchor(pos=ad.pos_cmd[None], rot=ad.rot_cmd[None])
        return reps.encode(self.fmt, track, ad.fps, anchor, where="expert action")[0].astype(np.float32)
