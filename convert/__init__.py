"""demo.convert: action representations and the conversions between them.

Modules (import them directly; this package imports nothing, so ``demo --help`` stays fast):

- :mod:`demo.convert.representations`: the registry (``joint_pos``, ``joint_vel``, ``ee_abs``,
  ``ee_delta``, ``ee7``) and, in its docstring, every convention (frames, Euler order, delta
  composition, anchors, gripper range and sign). ``make_format``, ``parse_spec``, ``encode``,
  ``decode``.
- :mod:`demo.convert.kinematics`: ``Kinematics``, batched FK of the EE site in the base frame.
- :mod:`demo.convert.ik`: ``IKSolver`` (mink, daqp), converged and warm-started per frame.
- :mod:`demo.convert.context`: the robot and task scene a store names.
- :mod:`demo.convert.convert`: ``convert_store`` (store -> new store) and ``Converter`` (arrays).
- :mod:`demo.convert.check`: ``replay_check`` (simulator replay) and ``round_trip``.
- :mod:`demo.convert.adapter`: ``make_adapter(spec, env)``, executes any representation on a
  ``joint_pos`` environment (IK each step for EE actions).
"""
