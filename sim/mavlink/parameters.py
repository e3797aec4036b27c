"""The autopilot's parameters and the parameter protocol: PARAM_REQUEST_LIST, PARAM_REQUEST_READ,
PARAM_SET, each answered with PARAM_VALUE (name, value, type, count, index).

The set is the personality's (:mod:`sim.personality`), with the system id and the vehicle's
real hover thrust filled in.  The thrust curve parameter (PX4's THR_MDL_FAC, ArduPilot's
MOT_THST_EXPO) is what the vehicle's firmware linearises its motor outputs with: set (at start
or with PARAM_SET), it moves the hover point of a vehicle whose motors have another curve, and
the hover parameter (MPC_THR_HOVER / MOT_THST_HOVER) is set to the new one.  An INT32 travels as PX4 sends it, its bytes in the float
(PARAM_ENCODE_BYTEWISE), or as ArduPilot does, cast to a float (PARAM_ENCODE_C_CAST).  The
SIM_WIND_* parameters are the ground station's wind: setting one lays a constant wind and
Dryden turbulence over the vehicle's own.
"""

import math
import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .. import personality as PP
from .. import wind as W


def parse_param(ap, name, value):
    """The initial value of parameter ``name`` of personality ``ap`` from a number or its text;
    ValueError for a name the personality does not have or a value its type cannot hold."""
    types = {n: t for n, _, t in ap.params}
    if name not in types:
        raise ValueError(f"unknown parameter {name!r} for the {ap.name} personality "
                         f"(known: {', '.join(sorted(types))})")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"parameter {name}: {value!r} is not a number") from None
    if not math.isfinite(x):
        raise ValueError(f"parameter {name}: {value!r} is not a finite number")
    if types[name] == PP.INT:
        if x != int(x):
            raise ValueError(f"parameter {name} is an integer (got {value!r})")
        return int(x)
    return x


def _param_id(msg):
    return msg.param_id.decode(errors="replace") if isinstance(msg.param_id, bytes) else msg.param_id


class Parameters:
    """The parameters of personality ``ap`` for ``vehicle`` as system ``sysid``, with the
    initial values ``initial`` ({name: value}); ``values`` is {name: (value, MAV_PARAM_TYPE)}."""

    def __init__(self, ap, vehicle, sysid, initial, statustext, statustext_limited):
        self.ap = ap
        self.vehicle = vehicle
        self._say = statustext
        self._say_limited = statustext_limited
        self.values = {name: (default, ptype) for name, default, ptype in ap.params}
        self.values[ap.sysid_param] = (sysid, PP.INT)
        self.names = [name for name, _, _ in ap.params]
        for name, value in (initial or {}).items():
            self.values[name] = (parse_param(ap, name, value), self.values[name][1])
        self._apply_thrust_model()
        if ap.hover_param not in (initial or {}):
            self.values[ap.hover_param] = (float(vehicle.hover_thrust), PP.REAL)
        self._base_wind = vehicle.wind
        if any(name.startswith("SIM_WIND_") for name in (initial or {})):
            self._update_wind(announce=False)

    def _encode(self, name):
        value, ptype = self.values[name]
        if ptype == PP.INT and self.ap.bytewise_params:
            return struct.unpack("<f", struct.pack("<i", int(value)))[0], ptype
        return float(value), ptype

    def _send_value(self, link, name):
        value, ptype = self._encode(name)
        link.mav.send(mavlink.MAVLink_param_value_message(name.encode(), value, ptype,
                                                          len(self.names),
                                                          self.names.index(name)))

    def on_request_list(self, link, msg):
        for name in self.names:
            self._send_value(link, name)

    def on_request_read(self, link, msg):
        """By index if param_index >= 0, else by name; nothing for one that does not exist."""
        if msg.param_index >= 0:
            if msg.param_index < len(self.names):
                self._send_value(link, self.names[msg.param_index])
            return
        name = _param_id(msg)
        if name in self.values:
            self._send_value(link, name)

    def on_set(self, link, msg):
        """Set and answer with the value now held (the old one if the new one is refused)."""
        name = _param_id(msg)
        if name not in self.values:
            self._say_limited("param:" + name, mavlink.MAV_SEVERITY_WARNING,
                              f"Unknown parameter {name}")
            return
        _, ptype = self.values[name]
        raw = msg.param_value
        if ptype == PP.INT:
            if self.ap.bytewise_params and msg.param_type == PP.INT:
                value = struct.unpack("<i", struct.pack("<f", raw))[0]
            elif math.isfinite(raw):
                value = int(round(raw))
            else:
                value = None
        else:
            value = float(raw) if math.isfinite(raw) else None
        if value is None:
            self._say_limited("param:" + name, mavlink.MAV_SEVERITY_WARNING,
                              f"Parameter {name}: value refused")
        else:
            old = self.values[name]
            self.values[name] = (value, ptype)
            if name.startswith("SIM_WIND_"):
                self._update_wind()
            if name == self.ap.thrust_model_param:
                # the hover point moves with the linearisation; it is reported at once
                try:
                    self._apply_thrust_model()
                except ValueError as exc:
                    self.values[name] = old
                    self._apply_thrust_model()
                    self._say_limited("param:" + name, mavlink.MAV_SEVERITY_WARNING,
                                      f"Parameter {name}: value refused ({exc})"[:50])
                self.values[self.ap.hover_param] = (float(self.vehicle.hover_thrust), PP.REAL)
        self._send_value(link, name)

    def _apply_thrust_model(self):
        """The vehicle's firmware linearises with the thrust curve parameter's factor."""
        value = self.values[self.ap.thrust_model_param][0]
        self.vehicle.set_thrust_model_factor(self.ap.thrust_model_factor(value))

    def _update_wind(self, announce=True):
        spd = float(self.values["SIM_WIND_SPD"][0])
        direction = float(self.values["SIM_WIND_DIR"][0])
        turb = float(self.values["SIM_WIND_TURB"][0])
        vert = float(self.values["SIM_WIND_DIR_Z"][0])
        parts = []
        if spd > 0.0 or vert != 0.0:
            parts.append(W.ConstantWind(max(spd, 0.0), direction, vertical=vert))
        if turb > 0.0:
            parts.append(W.DrydenTurbulence(w20=turb, seed=self.vehicle.seed))
        extra = W.CompositeWind(parts, seed=self.vehicle.seed) if parts else None
        self.vehicle.wind = W.LayeredWind.over(self._base_wind, extra)
        if announce:
            self._say(mavlink.MAV_SEVERITY_INFO,
                      f"Wind {spd:.1f} m/s from {direction:.0f} deg, turbulence {turb:.1f}")
