"""The companion's MAVLink link: transport, commands, parameters, timesync, samples."""
