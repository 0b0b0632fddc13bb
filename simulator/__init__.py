"""Gazebo-like 6-DOF underwater simulator: gz-sim's Hydrodynamics + Buoyancy equations.

World ENU, body FLU, quaternions (x, y, z, w), sim time int64 ns, 1 ms steps, poses published
at 50 Hz. See :mod:`uwval.simulator.dynamics` for the equations, :mod:`uwval.simulator.vehicle` for
parameters, :mod:`uwval.simulator.inputs` for wrench/current profiles (wrench in the body frame by
default) and :mod:`uwval.simulator.experiment` for the experiment TOML format.
"""

from uwval.simulator.dynamics import coriolis_matrix, damping_matrix, hydro_wrench_reference
from uwval.simulator.engine import (
    AT_REST,
    CAMERA_TOPIC,
    VEHICLE_TOPIC,
    InitialState,
    SimResult,
    SimulationStream,
    Simulator,
    TickChunk,
    camera_poses,
    simulate,
    simulate_batch,
)
from uwval.simulator.experiment import Experiment, Factor, RunSpec, load_experiment
from uwval.simulator.inputs import (
    TELEOP_KEYS,
    Constant,
    InputProfile,
    KeyPress,
    KeyScript,
    PulseTrain,
    Ramp,
    Signal,
    Step,
    constant_inputs,
)
from uwval.simulator.model import (
    FLUID_ADDED_MASS,
    PLUGIN_ADDED_MASS,
    AddedMass,
    CaSign,
    CoriolisEntries,
    GazeboModel,
)
from uwval.simulator.presets import load_vehicle, preset_names
from uwval.simulator.sdf import load_vehicle_sdf
from uwval.simulator.thrusters import Thrusters
from uwval.simulator.vehicle import Vehicle

__all__ = [
    "AT_REST",
    "CAMERA_TOPIC",
    "FLUID_ADDED_MASS",
    "PLUGIN_ADDED_MASS",
    "TELEOP_KEYS",
    "VEHICLE_TOPIC",
    "AddedMass",
    "CaSign",
    "Constant",
    "CoriolisEntries",
    "Experiment",
    "Factor",
    "GazeboModel",
    "InitialState",
    "InputProfile",
    "KeyPress",
    "KeyScript",
    "PulseTrain",
    "Ramp",
    "RunSpec",
    "Signal",
    "SimResult",
    "SimulationStream",
    "Simulator",
    "Step",
    "Thrusters",
    "TickChunk",
    "Vehicle",
    "camera_poses",
    "constant_inputs",
    "coriolis_matrix",
    "damping_matrix",
    "hydro_wrench_reference",
    "load_experiment",
    "load_vehicle",
    "load_vehicle_sdf",
    "preset_names",
    "simulate",
    "simulate_batch",
]
