"""The chaos runs' deadlines (bench/chaos.py, bench/chaos_study.py): from a fault to every
command register at 0, from the parameters they come from (docs/safety.md has the same)."""

# ---- parameters the deadlines come from (config/params/guidance.yaml, sim.yaml)
COMMAND_TIMEOUT_S = 0.5    # plc_output
WRITE_PERIOD_S = 1 / 50    # plc_output write_rate_hz
MODBUS_TIMEOUT_S = 0.2     # plc_output
WATCHDOG_S = 0.5           # mock_plc
SCAN_S = 1 / 100           # mock_plc update_hz
GAZE_TIMEOUT_S = 0.3       # pressure_controller
CONTROL_PERIOD_S = 1 / 30  # pressure_controller control_rate_hz

# ---- deadlines, from the fault to every command register at 0 (the same as docs/safety.md's)
#: The controller gone or frozen: plc_output's command_timeout_s, a write cycle, delivery slack.
CONTROLLER_VENT_S = COMMAND_TIMEOUT_S + WRITE_PERIOD_S + 0.5
#: plc_output gone or frozen, or the link dead: the PLC's watchdog at its next scan, slack.
WATCHDOG_VENT_S = WATCHDOG_S + SCAN_S + 0.5
#: No gaze reaches the controller: gaze_timeout_s, a control period, a write cycle, slack.
GAZE_STALE_VENT_S = GAZE_TIMEOUT_S + CONTROL_PERIOD_S + WRITE_PERIOD_S + 0.6
#: How late the delayed link delivers every byte, each way: beyond the request timeout.
LINK_DELAY_S = 0.5
#: A delayed link: what was sent before lands LINK_DELAY_S late, then the watchdog.
LINK_DELAY_VENT_S = LINK_DELAY_S + WATCHDOG_VENT_S
#: The operator's enable false or vent: the controller publishes zeros in the service call,
#: plc_output writes them at its next cycle; delivery slack.
OPERATOR_VENT_S = WRITE_PERIOD_S + 0.5
