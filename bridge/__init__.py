"""The ROS-TCP bridge (DESIGN.md section 6): Unity's ROS-TCP-Endpoint/Connector v0.7 link.

- :mod:`bridge.protocol`: framing, system commands, PoseStamped bodies (ROS 1 / ROS 2 CDR);
- :mod:`bridge.server`: the endpoint (TCP server, default 127.0.0.1:10000);
- :mod:`bridge.gazebo`: the Gazebo-side publisher and pose ticks;
- :mod:`bridge.unity_client`: the Unity-like client (connection, faults, render loop);
- :mod:`bridge.recorder`: incremental, crash-tolerant logging of both sides;
- :mod:`bridge.session`: ``run_session``, one bridged run on a virtual clock;
- :mod:`bridge.replay`: serve a recorded Gazebo-side log to Unity clients.
"""
