"""Vehicle parameters: the dataclass, its packed float vector for the kernels, and YAML loading.

Rotor numbering and spin directions (body FRD; ``rotor_directions[i] = +1`` means the rotor turns
counter-clockwise seen from above, so its drag torque on the body is +z, nose right):

- ``plus`` (the thesis, sec. 4.1 and eq. 3): rotor 1 front (+x), 2 right (+y), 3 rear (-x),
  4 left (-y); directions [-1, +1, -1, +1], the signs of the thesis's U4 row.
- ``x`` (PX4 quad-x): rotor 1 front-right, 2 rear-left, 3 front-left, 4 rear-right;
  1 and 2 counter-clockwise, 3 and 4 clockwise: directions [+1, +1, -1, -1].

The allocation maps squared rotor speeds to collective thrust T (N, along -z body) and body torques:
``[T, tau_x, tau_y, tau_z] = allocation_matrix() @ Omega**2`` with, per rotor at (x_i, y_i),
thrust k_f*Omega^2: tau_x = -y_i*k_f*Omega^2, tau_y = +x_i*k_f*Omega^2, tau_z = s_i*k_m*Omega^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from mavadrc.control.geometry import GRAVITY
from sim.yamlio import ConfigError, Section, config_path, load_yaml

__all__ = [
    "VehicleParams", "load_vehicle", "physical_problems",
    "P_MASS", "P_IXX", "P_IYY", "P_IZZ", "P_KF", "P_KM", "P_TAU_UP", "P_TAU_DOWN",
    "P_OMEGA_MIN", "P_OMEGA_MAX", "P_DRAG_LIN", "P_DRAG_QUAD", "P_ROTOR_DRAG",
    "P_ROTOR_INERTIA", "P_ROTOR_POS", "P_ROTOR_DIR", "P_SIZE",
]

# Layout of the packed parameter vector (VehicleParams.pack()).
P_MASS = 0
P_IXX = 1
P_IYY = 2
P_IZZ = 3
P_KF = 4
P_KM = 5
P_TAU_UP = 6
P_TAU_DOWN = 7
P_OMEGA_MIN = 8
P_OMEGA_MAX = 9
P_DRAG_LIN = 10       # 3 values, body x, y, z
P_DRAG_QUAD = 13      # 3 values, body x, y, z
P_ROTOR_DRAG = 16
P_ROTOR_INERTIA = 17
P_ROTOR_POS = 18      # 4 x 3 values, rotor i at P_ROTOR_POS + 3*i
P_ROTOR_DIR = 30      # 4 values
P_SIZE = 34

LAYOUTS = ("plus", "x")


@dataclass
class VehicleParams:
    """A rigid quadrotor with four first-order motors and a drag model. SI units throughout.

    Drag acts on the air-relative velocity v_a (body axes): linear ``-drag_linear * v_a`` and
    quadratic ``-drag_quadratic * |v_a| * v_a`` per body axis (drag_quadratic = 0.5*rho*Cd*A), plus
    rotor drag ``-rotor_drag * Omega_i * (v_a at rotor i, in the rotor plane)`` per rotor.
    """

    name: str
    mass: float                    # kg
    inertia: np.ndarray            # (3,) kg m^2, principal, body FRD
    arm_length: float              # m, centre to rotor axis
    layout: str                    # 'plus' | 'x'
    k_f: float                     # N / (rad/s)^2
    k_m: float                     # N m / (rad/s)^2
    tau_up: float                  # s, motor time constant when speeding up
    tau_down: float                # s, when slowing down
    omega_min: float               # rad/s
    omega_max: float               # rad/s
    drag_linear: np.ndarray = field(default_factory=lambda: np.zeros(3))     # N/(m/s)
    drag_quadratic: np.ndarray = field(default_factory=lambda: np.zeros(3))  # N/(m/s)^2
    rotor_drag: float = 0.0        # N / (m/s) / (rad/s)
    rotor_inertia: float = 0.0     # kg m^2, each rotor about its axis
    description: str = ""
    #: closed-loop bandwidth (rad/s) per axis of the autopilot's PX4-like attitude loop (None:
    #: the firmware's default for fast motors); a vehicle whose autopilot answers an attitude
    #: command slowly, as real ones do, gets a lower one
    attitude_bandwidth: Any = None
    #: the motors' real thrust curve: rotor thrust, as a fraction of its range, is
    #: ``k u^2 + (1 - k) u`` of the normalized motor output u (k in [-1, 1]; 0: thrust linear in
    #: the output, 1: rotor speed linear in it).  This is what an autopilot's THR_MDL_FAC (PX4,
    #: default 0) or MOT_THST_EXPO (ArduPilot, default 0.65) is set to match.  None: the motors
    #: have whatever curve the autopilot assumes, so thrust is exactly linear in the command
    motor_thrust_curve: Any = None

    def __post_init__(self) -> None:
        self.inertia = np.array(self.inertia, dtype=float).reshape(3)
        self.drag_linear = np.broadcast_to(np.asarray(self.drag_linear, dtype=float), 3).copy()
        self.drag_quadratic = np.broadcast_to(
            np.asarray(self.drag_quadratic, dtype=float), 3).copy()
        if self.motor_thrust_curve is not None:
            self.motor_thrust_curve = float(self.motor_thrust_curve)
        if self.attitude_bandwidth is not None:
            self.attitude_bandwidth = np.broadcast_to(
                np.asarray(self.attitude_bandwidth, dtype=float), 3).copy()
        problems = physical_problems({f.name: getattr(self, f.name) for f in fields(self)})
        if problems:
            name, reason = problems[0]
            raise ConfigError(f"vehicle {self.name!r}: {name}: {reason}")

    @property
    def weight(self) -> float:
        return self.mass * GRAVITY

    @property
    def max_thrust(self) -> float:
        """Collective thrust with all rotors at omega_max (N)."""
        return 4.0 * self.k_f * self.omega_max ** 2

    @property
    def thrust_to_weight(self) -> float:
        return self.max_thrust / self.weight

    @property
    def hover_omega(self) -> float:
        """Rotor speed (rad/s) at which four rotors carry the weight."""
        return math.sqrt(self.weight / (4.0 * self.k_f))

    @property
    def hover_thrust_norm(self) -> float:
        """Hover thrust as a fraction of max_thrust (thrust-linear normalisation)."""
        return self.weight / self.max_thrust

    @property
    def rotor_positions(self) -> np.ndarray:
        """(4, 3) rotor hub positions in body FRD (m), in the rotor order of the layout."""
        a = self.arm_length
        if self.layout == "plus":
            pos = [(a, 0.0, 0.0), (0.0, a, 0.0), (-a, 0.0, 0.0), (0.0, -a, 0.0)]
        else:
            d = a / math.sqrt(2.0)
            pos = [(d, d, 0.0), (-d, -d, 0.0), (d, -d, 0.0), (-d, d, 0.0)]
        return np.array(pos)

    @property
    def rotor_directions(self) -> np.ndarray:
        """(4,) +1 counter-clockwise seen from above (yaw torque +z FRD), -1 clockwise."""
        if self.layout == "plus":
            return np.array([-1.0, 1.0, -1.0, 1.0])
        return np.array([1.0, 1.0, -1.0, -1.0])

    def allocation_matrix(self) -> np.ndarray:
        """(4, 4): squared rotor speeds -> [collective thrust N, tau_x, tau_y, tau_z N m]."""
        pos = self.rotor_positions
        A = np.empty((4, 4))
        A[0] = self.k_f
        A[1] = 0.0 - self.k_f * pos[:, 1]
        A[2] = self.k_f * pos[:, 0]
        A[3] = self.k_m * self.rotor_directions
        return A

    def as_file(self) -> dict[str, Any]:
        """The vehicle as a vehicle file's keys (plain values): :func:`load_vehicle` of its YAML
        gives this vehicle back."""
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None:
                continue
            out[f.name] = [float(a) for a in v] if isinstance(v, np.ndarray) else v
        return out

    def pack(self) -> np.ndarray:
        """The float64 parameter vector the physics kernels take (indices P_*)."""
        P = np.zeros(P_SIZE)
        P[P_MASS] = self.mass
        P[P_IXX:P_IXX + 3] = self.inertia
        P[P_KF] = self.k_f
        P[P_KM] = self.k_m
        P[P_TAU_UP] = self.tau_up
        P[P_TAU_DOWN] = self.tau_down
        P[P_OMEGA_MIN] = self.omega_min
        P[P_OMEGA_MAX] = self.omega_max
        P[P_DRAG_LIN:P_DRAG_LIN + 3] = self.drag_linear
        P[P_DRAG_QUAD:P_DRAG_QUAD + 3] = self.drag_quadratic
        P[P_ROTOR_DRAG] = self.rotor_drag
        P[P_ROTOR_INERTIA] = self.rotor_inertia
        P[P_ROTOR_POS:P_ROTOR_POS + 12] = self.rotor_positions.reshape(12)
        P[P_ROTOR_DIR:P_ROTOR_DIR + 4] = self.rotor_directions
        return P


def physical_problems(v: dict[str, Any]) -> list[tuple[str, str]]:
    """(field, reason) for every value that makes no physical sense, first problem first."""
    out: list[tuple[str, str]] = []

    def positive(name: str, strict: bool = True) -> bool:
        values = np.atleast_1d(np.asarray(v[name], dtype=float))
        bad = ~np.isfinite(values) | ((values <= 0) if strict else (values < 0))
        if bad.any():
            shown = v[name] if np.ndim(v[name]) == 0 else list(np.atleast_1d(v[name]))
            out.append((name, f"must be {'>' if strict else '>='} 0 (got {shown})"))
            return False
        return True

    ok = all([positive("mass"), positive("inertia"), positive("arm_length"), positive("k_f"),
              positive("tau_up"), positive("tau_down"), positive("omega_max")])
    positive("k_m", strict=False)
    omin_ok = positive("omega_min", strict=False)
    for name in ("drag_linear", "drag_quadratic", "rotor_drag", "rotor_inertia"):
        positive(name, strict=False)
    k = v.get("motor_thrust_curve")
    if k is not None and not (math.isfinite(float(k)) and -1.0 <= float(k) <= 1.0):
        out.append(("motor_thrust_curve", f"must be in [-1, 1] (got {k}): outside it the "
                                          "thrust is not monotonic in the motor output"))
    if v["layout"] not in LAYOUTS:
        out.append(("layout", f"must be one of {', '.join(LAYOUTS)} (got {v['layout']!r})"))
    if omin_ok and ok and v["omega_min"] >= v["omega_max"]:
        out.append(("omega_min", f"must be < omega_max = {v['omega_max']} "
                                 f"(got {v['omega_min']})"))
    if ok:
        weight = v["mass"] * GRAVITY
        tw = 4.0 * v["k_f"] * v["omega_max"] ** 2 / weight
        if tw < 1.0:
            out.append(("omega_max", f"thrust-to-weight 4*k_f*omega_max^2/(mass*g) = {tw:.3f} "
                                     "< 1: the vehicle cannot lift itself"))
        if omin_ok and 4.0 * v["k_f"] * v["omega_min"] ** 2 >= weight:
            out.append(("omega_min", "thrust at omega_min already carries the weight: "
                                     "the vehicle cannot descend"))
    return out


def load_vehicle(name_or_path: str | Path) -> VehicleParams:
    """Load a vehicle from YAML; a bare name means configs/vehicles/NAME.yaml.

    Raises ConfigError naming the file, line and field for a malformed or impossible file.
    """
    path = config_path(name_or_path, "vehicles")
    sec = Section(load_yaml(path), str(path))
    values = {
        "name": sec.string("name", path.stem),
        "mass": sec.number("mass", gt=0),
        "inertia": sec.vector("inertia", 3, gt=0),
        "arm_length": sec.number("arm_length", gt=0),
        "layout": sec.string("layout", choices=LAYOUTS),
        "k_f": sec.number("k_f", gt=0),
        "k_m": sec.number("k_m", ge=0),
        "tau_up": sec.number("tau_up", gt=0),
        "tau_down": sec.number("tau_down", gt=0),
        "omega_min": sec.number("omega_min", 0.0, ge=0),
        "omega_max": sec.number("omega_max", gt=0),
        "drag_linear": sec.vector("drag_linear", 3, (0.0, 0.0, 0.0), scalar_ok=True, ge=0),
        "drag_quadratic": sec.vector("drag_quadratic", 3, (0.0, 0.0, 0.0), scalar_ok=True,
                                     ge=0),
        "rotor_drag": sec.number("rotor_drag", 0.0, ge=0),
        "rotor_inertia": sec.number("rotor_inertia", 0.0, ge=0),
        "description": sec.string("description", ""),
        "attitude_bandwidth": (sec.vector("attitude_bandwidth", 3, scalar_ok=True, gt=0)
                               if sec.has("attitude_bandwidth") else None),
        "motor_thrust_curve": sec.number("motor_thrust_curve", None, ge=-1.0, le=1.0),
    }
    sec.finish()
    for name, reason in physical_problems(values):
        sec.error(name, reason)
    return VehicleParams(**values)
