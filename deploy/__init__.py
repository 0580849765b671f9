"""From a trained run to a robot's control loop: a policy server and a real-time client.

- :mod:`.protocol`: frames and chunks as msgpack over a WebSocket.
- :mod:`.server`: ``demo serve RUN``, observation -> action chunk.
- :mod:`.controller`: the robot-side loop at the control rate: chunks merged as they arrive, safety
  limits, hold-and-stop on stale data.
- :mod:`.sim_robot`: the simulator as a stand-in robot, a separate process stepping physics in real time.
"""
