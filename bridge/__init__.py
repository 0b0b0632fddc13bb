"""The ROS-TCP bridge (DESIGN.md section 6): Unity's ROS-TCP-Endpoint/Connector v0.7 link.

- :mod:`uwval.bridge.protocol`: framing, system commands, PoseStamped bodies (ROS 1 / ROS 2 CDR);
- :mod:`uwval.bridge.server`: the endpoint (TCP server, default 127.0.0.1:10000);
- :mod:`uwval.bridge.gazebo`: the Gazebo-side publisher and pose ticks;
- :mod:`uwval.bridge.unity_client`: the Unity-like client (connection, faults, render loop);
- :mod:`uwval.bridge.recorder`: incremental, crash-tolerant logging of both sides;
- :mod:`uwval.bridge.options`: ``SessionOptions``, how one bridged run behaves (light import);
- :mod:`uwval.bridge.session`: ``BridgeSession`` / ``run_session``, one bridged run on a virtual
  clock;
- :mod:`uwval.bridge.replay`: serve a recorded Gazebo-side log to Unity clients.
"""
