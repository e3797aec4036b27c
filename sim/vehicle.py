"""The bundled vehicle in process: physics, wind, sensors and the autopilot's firmware loops.

:class:`SimVehicle` is the API the tests, the MAVLink server and batch experiments use::

    v = SimVehicle("x500", wind="moderate_gusts", seed=3)
    v.arm()
    v.takeoff(2.0)
    v.step(5.0)                 # advance 5 s of simulated time
    r = v.reported()            # what the sensors report: position, velocity, attitude, rates

Every physics step (``physics_dt``, 1 kHz by default) the wind is sampled, the firmware's inner
loop (attitude control + mixer, :mod:`sim.firmware.attitude`) runs (every step, or every k-th with
``attitude_rate_hz``) and the rigid body advances one RK4 step.  The position loop, the flight
modes and the land detector run at ``position_rate_hz``.  Without a sensor model the steps between
two position-loop ticks run in one compiled call, wind included when it has a compiled form
(:func:`sim.wind.pack_wind`: the bundled wind files all do).  The same seed gives the same
flight, however the time is cut into ``step`` calls.
"""

import dataclasses
import math

import numpy as np

from mavadrc.control import geometry as G
from mavadrc.control.jit import jit

from . import physics as phys
from .firmware import attitude as A
from .firmware import position as PL
from .firmware.mixer import Mixer, curve_mismatch, hover_command
from .flight_modes import (IGNORE_ATTITUDE, IGNORE_PITCH_RATE, IGNORE_ROLL_RATE, IGNORE_THRUST,
                           IGNORE_YAW_RATE, MODES, CommandRejected, FlightModes)
from .kernel_state import KernelState
from .params import VehicleParams, load_vehicle
from .reporting import (GROUND_CLIMB_DECAY_S, GROUND_CLIMB_FLOWN_M, GROUND_CLIMB_HOLD_S,
                        GROUND_CLIMB_REST_M, Reported, Reporting)
from .sensors import Sensors, measure_into
from .wind import WIND_SCRATCH, Wind, load_wind, pack_wind, wind_step_packed

# the flight modes' and the sensor side's names are imported from here too (their old home)
__all__ = [
    "SimVehicle", "Firmware", "Reported", "CommandRejected", "MODES", "IGNORE_ROLL_RATE",
    "IGNORE_PITCH_RATE", "IGNORE_YAW_RATE", "IGNORE_THRUST", "IGNORE_ATTITUDE",
    "GROUND_CLIMB_HOLD_S", "GROUND_CLIMB_DECAY_S", "GROUND_CLIMB_FLOWN_M", "GROUND_CLIMB_REST_M",
    "RANDOM_HEADING", "advance", "advance_wind", "advance_wind_into", "advance_wind_measured_into",
    "child_seeds", "divider", "initial_heading", "parse_heading", "resolve_vehicle",
    "resolve_wind", "response_time_constants", "vehicle_variant",
]


@jit
def advance(x, xm, fs, fp, S, P, W, mx, sp, omega, wk, pv, v_wind, f_ext, tau_ext, dt, n, tick,
            att_div, pos_div, pos_dt):
    """n physics steps of one vehicle with its firmware inner loop and land detector.

    ``xm`` is what the firmware measures (x itself for truth); ``wk`` the firmware's scratch;
    inputs held over the n steps.
    """
    for k in range(n):
        t = tick + k
        if t % pos_div == 0:
            PL.land_detect(fs, fp, sp[A.SP_THRUST], xm[3:6], pos_dt)
        if t % att_div == 0:
            A.inner_step(fs, fp, S, P, W, mx, xm, sp, omega, wk)
        phys.step(x, omega, pv, v_wind, f_ext, tau_ext, dt)


@jit
def advance_wind(x, xm, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate, eta, v_wind, f_ext,
                 tau_ext, dt, n, tick, att_div, pos_div, pos_dt):
    """:func:`advance` with a packed wind (:func:`sim.wind.pack_wind`) evaluated every step at
    the step's start; ``eta`` holds the Dryden normals of these n steps, row by row."""
    advance_wind_into(x, xm, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate, eta, v_wind,
                      f_ext, tau_ext, dt, n, tick, att_div, pos_div, pos_dt,
                      np.empty(WIND_SCRATCH), np.empty((5, phys.NX)))


@jit
def advance_wind_into(x, xm, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate, eta, v_wind,
                      f_ext, tau_ext, dt, n, tick, att_div, pos_div, pos_dt, scratch, ws):
    """:func:`advance_wind` with its work arrays passed in (``scratch``: WIND_SCRATCH floats,
    ``ws``: (5, NX)), for compiled loops that call it every control period."""
    for k in range(n):
        t = tick + k
        wind_step_packed(wp, dstate, eta, k, t * dt, dt, x, v_wind, f_ext, tau_ext, scratch)
        if t % pos_div == 0:
            PL.land_detect(fs, fp, sp[A.SP_THRUST], xm[3:6], pos_dt)
        if t % att_div == 0:
            A.inner_step(fs, fp, S, P, W, mx, xm, sp, omega, wk)
        phys.rk4_step(x, omega, pv, v_wind, f_ext, tau_ext, dt, ws)


@jit
def advance_wind_measured_into(x, xm, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate, eta,
                               noise, sig, v_wind, f_ext, tau_ext, dt, n, tick, att_div, pos_div,
                               pos_dt, scratch, ws):
    """:func:`advance_wind_into` with a sensor model: n steps one by one, the firmware flying on
    the estimate ``xm``, into which each step's end state is read with that step's row of
    ``noise`` (:meth:`sim.sensors.Sensors.draws`, ``sig`` its sigmas)."""
    for k in range(n):
        advance_wind_into(x, xm, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate,
                          eta[k:k + 1], v_wind, f_ext, tau_ext, dt, 1, tick + k, att_div, pos_div,
                          pos_dt, scratch, ws)
        measure_into(x, noise[k], sig, xm)


def child_seeds(seed, n=2):
    """Independent integer seeds for the random parts of one vehicle: wind, sensors and (the
    third) the initial heading.  Child k is the same whatever ``n``, so asking for more
    streams leaves the first ones' draws as they were."""
    ss = np.random.SeedSequence(seed)
    return [int(c.generate_state(1)[0]) for c in ss.spawn(n)]


#: ``yaw`` (rad) that asks :class:`SimVehicle` for an initial heading drawn from its seed
RANDOM_HEADING = math.nan


def initial_heading(yaw, seed):
    """The initial heading (rad) a vehicle with ``seed`` starts at for ``yaw``: ``yaw`` itself,
    or, for :data:`RANDOM_HEADING` (NaN), one drawn uniformly in [-pi, pi) from the seed's own
    stream (the third of :func:`child_seeds`), so the wind's and the sensors' draws do not
    change.  The in-process path and the MAVLink server (``--heading random``) both call this."""
    yaw = float(yaw)
    if not math.isnan(yaw):
        return yaw
    rng = np.random.default_rng(child_seeds(seed, 3)[2])
    return float(rng.uniform(-math.pi, math.pi))


def parse_heading(text):
    """Degrees from ``--heading DEG`` or ``random`` (NaN: :data:`RANDOM_HEADING` once in rad)."""
    if str(text).strip().lower() == "random":
        return math.nan
    deg = float(text)
    if not math.isfinite(deg):
        raise ValueError(f"heading must be a finite number of degrees or 'random' (got {text!r})")
    return deg


def resolve_vehicle(vehicle):
    if isinstance(vehicle, VehicleParams):
        return vehicle
    return load_vehicle(vehicle)


def vehicle_variant(vehicle, *, mass_scale=1.0, motor_thrust_curve=None,
                    attitude_bandwidth_scale=1.0):
    """The vehicle with a few of its file's values changed, for robustness studies: the mass
    times ``mass_scale`` (a payload at the centre of mass: inertia, motors and the autopilot's
    gains as they were), the motors' real thrust curve ``motor_thrust_curve`` (None: the
    file's), and the PX4-like attitude loop's closed-loop bandwidth (the file's
    ``attitude_bandwidth``, or the firmware's default) times ``attitude_bandwidth_scale``.
    Raises ConfigError when the result cannot fly (too heavy to lift itself)."""
    vp = resolve_vehicle(vehicle)
    changes = {}
    if mass_scale != 1.0:
        changes["mass"] = vp.mass * float(mass_scale)
    if motor_thrust_curve is not None:
        changes["motor_thrust_curve"] = float(motor_thrust_curve)
    if attitude_bandwidth_scale != 1.0:
        changes["attitude_bandwidth"] = (float(attitude_bandwidth_scale)
                                         * A.default_bandwidths(vp, "px4"))
    return dataclasses.replace(vp, **changes) if changes else vp


def resolve_wind(wind, seed):
    """A Wind (reset with ``seed``) from None, a config name/path, a mapping or a Wind."""
    if wind is None:
        return None
    if isinstance(wind, Wind):
        wind.reset(seed)
        return wind
    return load_wind(wind, seed)


def divider(rate_hz, physics_dt, name):
    """Physics steps per tick of a loop running at ``rate_hz`` (None: every step)."""
    if rate_hz is None:
        return 1
    k = round(1.0 / (float(rate_hz) * physics_dt))
    if k < 1 or abs(k * physics_dt * rate_hz - 1.0) > 1e-6:
        raise ValueError(f"{name}={rate_hz!r} Hz must divide the physics rate "
                         f"{1.0 / physics_dt:g} Hz")
    return k


class Firmware:
    """The firmware's parameter and state arrays for one vehicle (shared by the batch form)."""

    def __init__(self, vp, *, attitude_controller, physics_dt, attitude_rate_hz,
                 position_rate_hz, max_thrust, hover_thrust, airmode, attitude_gains,
                 land_thrust=0.6, land_vz=0.25, land_vxy=1.0, land_time=0.5,
                 thrust_model_factor=0.0):
        self.att_div = divider(attitude_rate_hz, physics_dt, "attitude_rate_hz")
        self.pos_div = divider(position_rate_hz, physics_dt, "position_rate_hz")
        if max_thrust is not None and hover_thrust is not None:
            raise ValueError("give max_thrust or hover_thrust, not both")
        if hover_thrust is not None:
            if not 0.0 < hover_thrust < 1.0:
                raise ValueError(f"hover_thrust must be in (0, 1) (got {hover_thrust!r})")
            scale = vp.weight / float(hover_thrust)
        elif max_thrust is not None:
            scale = float(max_thrust)
            if not (math.isfinite(scale) and scale > vp.weight):
                raise ValueError(f"max_thrust must exceed the weight {vp.weight:.4g} N "
                                 f"(got {max_thrust!r})")
        else:
            scale = vp.max_thrust
        self.thrust_scale = scale
        self.vp = vp
        self.mixer = Mixer(vp, airmode=airmode)
        self.fp, self.P = A.firmware_params(
            vp, attitude_controller, h=physics_dt * self.att_div, thrust_scale=scale,
            mixer=self.mixer, **dict(attitude_gains or {}))
        self.land_thrust = land_thrust
        ld = self.fp[A.FP_LD:A.FP_LD + PL.NLD]
        ld[PL.LD_VZ] = land_vz
        ld[PL.LD_VXY] = land_vxy
        ld[PL.LD_TIME] = land_time
        self.set_thrust_model(thrust_model_factor)
        self.mx = self.mixer.params
        self.pos_dt = physics_dt * self.pos_div

    def set_thrust_model(self, factor):
        """The thrust curve factor the autopilot linearises its motor outputs with (PX4's
        THR_MDL_FAC, ArduPilot's MOT_THST_EXPO; in [-1, 1]); sets the hover thrust and the land
        detector's threshold that follow from it and the vehicle's real curve."""
        k = float(factor)
        if not (math.isfinite(k) and -1.0 <= k <= 1.0):
            raise ValueError(f"thrust model factor must be in [-1, 1] (got {factor!r})")
        vp = self.vp
        self.thrust_model_factor = k
        on = curve_mismatch(vp, k)
        self.fp[A.FP_CURVE] = 1.0 if on else 0.0
        self.fp[A.FP_CURVE_ASSUMED] = k
        self.fp[A.FP_CURVE_TRUE] = vp.motor_thrust_curve if on else k
        self.hover_thrust = hover_command(vp, self.thrust_scale, k)
        if not 0.0 < self.hover_thrust < 1.0:
            raise ValueError(f"{vp.name} cannot hover with thrust 1.0 = {self.thrust_scale:.4g} "
                             f"N and a thrust model factor of {k:g}")
        self.fp[A.FP_LD + PL.LD_THRUST] = self.land_thrust * self.hover_thrust


def _part_attribute(part, name, doc, settable=True):
    """An attribute of :class:`SimVehicle` that its part ``part`` keeps, read (and assigned)
    through."""
    def get(self):
        return getattr(getattr(self, part), name)

    def put(self, value):
        setattr(getattr(self, part), name, value)

    return property(get, put if settable else None, doc=doc)


def run_steps(ks, end, fw, rep, modes, wind, packed):
    """Step the vehicle whose kernel state is ``ks`` up to physics step ``end``: at each
    position-loop tick its flight modes (``modes``), between ticks the compiled kernels with its
    firmware ``fw``, its wind (``wind``; ``packed``: its compiled form, or None) and its sensor
    side (``rep``), step by step where only Python can sample them."""
    sensed = rep.sensors is not None
    # a sensor model without report latency reads every step in the compiled loop, its noise
    # drawn ahead for the steps up to the next position-loop tick
    measured = packed is not None and sensed and rep.report is None
    per_step = ((wind is not None and packed is None) or sensed) and not measured
    while ks.tick < end:
        tick = ks.tick
        if per_step or measured:
            rep.measure(ks)
        if tick % fw.pos_div == 0:
            modes.outer()
        n = 1 if per_step else min(end - tick, fw.pos_div - tick % fw.pos_div)
        if measured:
            est = rep.estimate
            advance_wind_measured_into(
                ks.x, rep.xm, ks.fs, fw.fp, ks.S, fw.P, ks.W, fw.mx, ks.sp, ks.omega, ks.wk,
                ks.pv, packed.params, packed.state, packed.normals(n), est.draws(n),
                est.sigmas(), ks.v_wind, ks.f_ext, ks.tau_ext, ks.physics_dt, n, tick,
                fw.att_div, fw.pos_div, fw.pos_dt, ks.scratch, ks.ws)
            ks.tick += n
            rep.measured_tick = ks.tick
            continue
        if packed is not None:
            advance_wind(ks.x, rep.firmware_input(ks), ks.fs, fw.fp, ks.S, fw.P, ks.W, fw.mx,
                         ks.sp, ks.omega, ks.wk, ks.pv, packed.params, packed.state,
                         packed.normals(n), ks.v_wind, ks.f_ext, ks.tau_ext, ks.physics_dt,
                         n, tick, fw.att_div, fw.pos_div, fw.pos_dt)
            ks.tick += n
            continue
        if wind is not None:
            t = tick * ks.physics_dt
            v, f, tau = wind.step(t, ks.physics_dt, ks.x[0:3], ks.x[3:6])
            ks.v_wind[:] = v
            ks.f_ext[:] = f
            ks.tau_ext[:] = tau
        advance(ks.x, rep.firmware_input(ks), ks.fs, fw.fp, ks.S, fw.P, ks.W, fw.mx, ks.sp,
                ks.omega, ks.wk, ks.pv, ks.v_wind, ks.f_ext, ks.tau_ext, ks.physics_dt, n,
                tick, fw.att_div, fw.pos_div, fw.pos_dt)
        ks.tick += n
    if per_step:
        rep.measure(ks)  # what is reported after the step is of its end, not a tick before


class SimVehicle:
    """A simulated multirotor with a PX4-like autopilot, stepped in process.

    ``vehicle``: a name in configs/vehicles, a YAML path or a VehicleParams.  ``wind``: None, a
    name in configs/wind, a path, a mapping or a :class:`sim.wind.Wind`.  ``sensors``: None
    (truth), a :class:`sim.sensors.Sensors` or its keyword mapping; its noise is what the
    firmware's loops see, its latency delays only what :meth:`reported` returns (the link to
    the companion), as an autopilot's inner loop runs on fresh gyro data whatever its telemetry
    lags.  ``attitude_controller``:
    'px4', 'ladrc', 'adrc' or 'pd'; ``attitude_gains`` override its gains (see
    :func:`sim.firmware.attitude.firmware_params`).  ``max_thrust`` (N) or ``hover_thrust``
    (normalized) set what normalized thrust 1.0 means (default: the rotors' maximum).
    ``thrust_model_factor``: the thrust curve the autopilot assumes when it turns thrust into
    motor outputs (PX4's THR_MDL_FAC, whose default 0 this is; ArduPilot's MOT_THST_EXPO); it
    matters only against a vehicle file that gives the motors' real ``motor_thrust_curve``.
    ``position_options``: keywords of :class:`sim.firmware.position.Navigator` (gains, speeds,
    tilt limit).  ``position``/``yaw``: start pose (``yaw`` NaN, :data:`RANDOM_HEADING`: a
    heading drawn from the seed, :func:`initial_heading`); above the ground the vehicle starts
    flying with its rotors at hover speed (disarmed until ``arm()``).  ``auto_disarm_s``: after a
    ``land()`` touches down, disarm this long after (None: stay armed at idle).

    Its parts, each handed what it works on: ``kernel`` (:class:`sim.kernel_state.KernelState`),
    the arrays the compiled kernels step; ``fw`` (:class:`Firmware`), the firmware's parameters;
    ``reporting`` (:class:`sim.reporting.Reporting`), the sensor side; ``modes``
    (:class:`sim.flight_modes.FlightModes`), the flight modes with the navigator ``nav``.
    """

    def __init__(self, vehicle="crazyflie", wind=None, seed=0, sensors=None,
                 attitude_controller="px4", physics_dt=0.001, attitude_rate_hz=None,
                 position_rate_hz=100.0, max_thrust=None, hover_thrust=None, airmode=True,
                 attitude_gains=None, position_options=None, position=(0.0, 0.0, 0.0), yaw=0.0,
                 auto_disarm_s=2.0, thrust_model_factor=0.0, height_drift_mps=0.0,
                 ground_climb_mps=0.0, rangefinder=False):
        self.params = vp = resolve_vehicle(vehicle)
        # a downward range finder (DISTANCE_SENSOR), measuring the true height above the ground
        # as PX4 SIH's does (simulator_sih: -z / cos(tilt), no noise)
        self.rangefinder = bool(rangefinder)
        drift = float(height_drift_mps)
        if not math.isfinite(drift):
            raise ValueError(f"height_drift_mps must be finite (got {height_drift_mps!r})")
        climb = float(ground_climb_mps)
        if not (math.isfinite(climb) and climb >= 0.0):
            raise ValueError(f"ground_climb_mps must be >= 0 (got {ground_climb_mps!r})")
        self.physics_dt = float(physics_dt)
        if not (math.isfinite(self.physics_dt) and self.physics_dt > 0.0):
            raise ValueError(f"physics_dt must be > 0 (got {physics_dt!r})")
        self.seed = seed
        wind_seed, sensor_seed = child_seeds(seed)
        self._wind = None
        self._packed = None
        self.wind = resolve_wind(wind, wind_seed)
        if isinstance(sensors, dict):
            sensors = Sensors(**sensors, seed=sensor_seed)
        self.reporting = Reporting(sensors, sensor_seed, self.physics_dt, drift, climb)
        self.fw = Firmware(vp, attitude_controller=attitude_controller,
                           physics_dt=self.physics_dt, attitude_rate_hz=attitude_rate_hz,
                           position_rate_hz=position_rate_hz, max_thrust=max_thrust,
                           hover_thrust=hover_thrust, airmode=airmode,
                           attitude_gains=attitude_gains, thrust_model_factor=thrust_model_factor)
        self.attitude_controller = attitude_controller
        self.nav = PL.Navigator(h=self.fw.pos_dt, hover_thrust=self.fw.hover_thrust,
                                **dict(position_options or {}))
        pos = np.asarray(position, dtype=float)
        self.initial_yaw = initial_heading(yaw, seed)
        self.kernel = KernelState(vp, self.fw, pos, self.initial_yaw, self.physics_dt)
        self.modes = FlightModes(self.kernel, self.nav, self.reporting, home=pos.copy(),
                                 auto_disarm_s=auto_disarm_s)
        self.reporting.measure(self.kernel)

    # -- read-outs -------------------------------------------------------------------------------
    @property
    def wind(self):
        """The wind model (a :class:`sim.wind.Wind` or None); assigning one takes effect at the
        next step."""
        return self._wind

    @wind.setter
    def wind(self, model):
        self._wind = model
        self._packed = pack_wind(model)

    sensors = _part_attribute("reporting", "sensors", """The sensor model (a
        :class:`sim.sensors.Sensors`) or None (truth).""", settable=False)
    height_drift_mps = _part_attribute("reporting", "height_drift_mps", """m/s the reported
        height drifts up by (a barometer's drift); the vehicle flies on the truth as before.""")
    ground_climb_mps = _part_attribute("reporting", "ground_climb_mps", """m/s of the climb the
        estimate reads once the vehicle, having flown, rests on the ground (0: none).""")
    auto_disarm_s = _part_attribute("modes", "auto_disarm_s", """s after a ``land()`` touches
        down that the vehicle disarms (None: it stays armed at idle).""")
    home = _part_attribute("modes", "home", """Where (NED) the vehicle was last armed on the
        ground; a takeoff's altitude is above it.""")

    @property
    def time(self):
        """Seconds since boot (simulated)."""
        return self.kernel.time

    @property
    def state(self):
        """Copy of the true state x (17): position, velocity, quaternion, body rates, rotors."""
        return self.kernel.x.copy()

    @property
    def armed(self):
        return self.kernel.armed

    @property
    def landed(self):
        return self.kernel.landed

    @property
    def mode(self):
        return self.modes.mode

    @property
    def hover_thrust(self):
        """Normalized thrust that holds a hover: weight / the thrust that 1.0 means, through the
        motors' real thrust curve when it differs from the autopilot's assumption."""
        return self.fw.hover_thrust

    @property
    def thrust_model_factor(self):
        """The thrust curve factor the autopilot linearises with (PX4's THR_MDL_FAC, ArduPilot's
        MOT_THST_EXPO); see :meth:`set_thrust_model_factor`."""
        return self.fw.thrust_model_factor

    def set_thrust_model_factor(self, factor):
        """Make the autopilot linearise its motor outputs with thrust curve factor ``factor``
        (rotor thrust fraction = f u^2 + (1 - f) u of motor output u, as PX4's THR_MDL_FAC,
        default 0, and ArduPilot's MOT_THST_EXPO, default 0.65, assume).  Against a vehicle
        whose ``motor_thrust_curve`` differs, thrust becomes nonlinear in the command and the
        hover thrust moves: :attr:`hover_thrust`, the land detector and the position loop
        follow at once."""
        self.fw.set_thrust_model(factor)
        self.nav.M[G.M_TPA] = self.fw.hover_thrust / self.nav.M[G.M_G]

    @property
    def rotor_commands(self):
        """Rotor speed commands of the last firmware step (rad/s)."""
        return self.kernel.omega.copy()

    @property
    def wrench(self):
        """[T, tau_x, tau_y, tau_z] the mixer achieved in the last firmware step (N, N m)."""
        return self.kernel.fs[A.FS_WRENCH:A.FS_WRENCH + 4].copy()

    @property
    def attitude_setpoint(self):
        """(quaternion, normalized thrust) the inner loop is tracking."""
        sp = self.kernel.sp
        return sp[A.SP_Q:A.SP_Q + 4].copy(), float(sp[A.SP_THRUST])

    @property
    def wind_velocity(self):
        """Air velocity at the vehicle over the last physics step (NED, m/s)."""
        return self.kernel.v_wind.copy()

    @property
    def observer(self):
        """(3, 3) Euler-channel observer estimates z1, z2, z3 per axis (ladrc/adrc kinds)."""
        return self.kernel.S[:, 0:3].copy()

    # -- the compiled kernels' view, for callers that run whole loops of them ---------------------
    def kernel_state(self):
        """The arrays :func:`advance_wind` steps, in its argument order (x .. pv): state, firmware
        state and parameters, setpoint, rotor commands, scratch, vehicle parameters."""
        return self.kernel.firmware_arrays(self.fw)

    def kernel_wind(self):
        """(packed wind, (v_wind, f_ext, tau_ext) output arrays) for :func:`advance_wind`; the
        packed form of calm air when there is no wind.  ValueError if the wind model has no
        compiled form (:func:`sim.wind.pack_wind`)."""
        packed = self._packed
        if packed is None:
            if self.wind is not None:
                raise ValueError("this wind has no compiled form (sim.wind.pack_wind)")
            packed = pack_wind(Wind())
        ks = self.kernel
        return packed, (ks.v_wind, ks.f_ext, ks.tau_ext)

    def kernel_sensors(self, ticks):
        """(xm, noise, sigmas) for a caller that runs the next ``ticks`` physics steps on
        :meth:`kernel_state` itself, step by step, reading each step's end state into ``xm`` with
        :func:`sim.sensors.measure_into` (``noise`` row by row), as :meth:`step` does: ``xm`` is
        the estimate the firmware flies on (the vehicle's own array, this tick's reading), the
        noise is taken now from the sensor model's own stream (:meth:`sim.sensors.Sensors.draws`),
        so it goes on where the vehicle's steps left it.  The sensor latency is the caller's to
        model.  Without noise: (the true state itself, no rows, zero sigmas)."""
        return self.reporting.kernel_sensors(self.kernel, ticks)

    @property
    def tick(self):
        """Physics steps since boot."""
        return self.kernel.tick

    def ran(self, ticks):
        """Account for ``ticks`` physics steps a caller ran on :meth:`kernel_state` itself with
        attitude setpoints (the vehicle is in attitude mode afterwards)."""
        ks = self.kernel
        ks.tick += int(ticks)
        ks.target_time = ks.tick * self.physics_dt
        self.modes.mode = "attitude"
        self.reporting.ran(ks)

    def reported(self):
        """The state as the vehicle reports it: truth, or with a sensor model the firmware's
        noisy estimate as of the last physics step, delayed by the model's latency."""
        return self.reporting.reported(self.kernel)

    def true_disturbance(self):
        """Acceleration (NED, m/s^2) the environment adds beyond rotor thrust and gravity.

        Drag on the air-relative velocity (wind and the vehicle's own motion), rotor drag and
        direct wind forces, divided by the mass, at the current state with the wind of the last
        step.  This is what a position-loop observer's disturbance estimate should approach.
        """
        ks = self.kernel
        a = np.empty(3)
        phys.disturbance_accel(ks.x, ks.omega, ks.pv, ks.v_wind, ks.f_ext, ks.tau_ext, a)
        return a

    # -- commands (:class:`sim.flight_modes.FlightModes`) ----------------------------------------
    def arm(self):
        self.modes.arm()

    def disarm(self, force=False):
        self.modes.disarm(force)

    def set_attitude_target(self, q, thrust, body_rates=None, type_mask=0):
        """Offboard attitude (quaternion [w, x, y, z] body -> NED) and normalized thrust 0..1.

        ``type_mask`` as SET_ATTITUDE_TARGET: 1/2/4 ignore roll/pitch/yaw rate, 64 ignore
        thrust (keep the last), 128 ignore the attitude (body rates only).  With an attitude,
        given rates are feed-forward.
        """
        self.modes.set_attitude_target(q, thrust, body_rates, type_mask)

    def set_position_target(self, pos=None, vel=None, acc=None, yaw=None, yaw_rate=None):
        """Offboard position/velocity/acceleration target (NED); None or NaN = ignored."""
        self.modes.set_position_target(pos, vel, acc, yaw, yaw_rate)

    def takeoff(self, altitude):
        """Climb to ``altitude`` m above home, then hold there."""
        self.modes.takeoff(altitude)

    def land(self, speed=None):
        """Descend where it is to the ground, at the firmware's land speed or ``speed`` (m/s)."""
        self.modes.land(speed)

    def hold(self):
        self.modes.hold()

    # -- simulation ------------------------------------------------------------------------------
    def step(self, dt):
        """Advance the simulation by dt seconds (a whole number of physics steps, rounded)."""
        if not (math.isfinite(dt) and dt >= 0.0):
            raise ValueError(f"dt must be >= 0 (got {dt!r})")
        ks = self.kernel
        ks.target_time += float(dt)
        end = int(math.floor(ks.target_time / self.physics_dt + 1e-6))
        run_steps(ks, end, self.fw, self.reporting, self.modes, self.wind, self._packed)


_LAGS = {}


def response_time_constants(vehicle="crazyflie", attitude_controller="px4", hover_thrust=None):
    """(tau_xy, tau_z): how fast the vehicle produces a commanded acceleration, measured.

    From a hover, a 1 m/s^2 horizontal (then vertical) acceleration step is commanded through
    SET_ATTITUDE_TARGET-style setpoints (the geometric map of :mod:`mavadrc.control.geometry`);
    each figure is the time the achieved acceleration takes to reach 63 % of the step: the
    attitude loop and the motors for the horizontal axes, the motors for the vertical one.  This
    is what a position loop's observers need to know about their input (``input_lag``).
    Deterministic; cached per vehicle and attitude controller.
    """
    vp = resolve_vehicle(vehicle)
    key = (repr(vp.pack().tolist()), repr(vp.attitude_bandwidth), vp.motor_thrust_curve,
           attitude_controller, hover_thrust)
    if key in _LAGS:
        return _LAGS[key]
    out = []
    h = 0.001
    for axis, step in ((0, (1.0, 0.0, 0.0)), (2, (0.0, 0.0, -1.0))):
        v = SimVehicle(vp, position=(0.0, 0.0, -10.0), attitude_controller=attitude_controller,
                       hover_thrust=hover_thrust)
        v.arm()
        m = G.mapping_params(hover_thrust=v.hover_thrust, tilt_max=math.radians(45.0))
        res = np.empty(G.NO)

        def command(a):
            G.accel_to_attitude(a[0], a[1], a[2], 0.0, m, res)
            v.set_attitude_target(res[G.O_Q:G.O_Q + 4], res[G.O_THRUST])

        command((0.0, 0.0, 0.0))
        v.step(0.3)  # settle at hover
        command(step)
        sign = step[axis]
        prev = float(v.state[3 + axis])
        for k in range(1, 1001):
            v.step(h)
            vel = float(v.state[3 + axis])
            if sign * (vel - prev) / h >= 0.632:
                out.append(k * h)
                break
            prev = vel
        else:
            raise RuntimeError(f"{vp.name}: no response to an acceleration step on axis "
                               f"{axis} within 1 s")
    _LAGS[key] = (out[0], out[1])
    return _LAGS[key]
