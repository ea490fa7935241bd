"""The paper's mathematics, the task logic and the wire formats as plain Python: no rclpy, no
ROS messages (the nodes, the simulation, the bench and the tests all run on it).

geometry               frames (Unity -> REP 103) and the horizontal/vertical target angles
power_law              P = a*theta^b + c, its inverse, the least-squares fit (Algorithm 1)
feedback               the gaze-error feedback law (Eq. 5), per direction and for all four
channels               direction pressures onto named suit/arm channels in a configured order
calibration            Algorithm 1 as a state machine, and the calibration file
conditions             the four guidance conditions of the experiments
speech                 the phrase of condition 4
task                   when a target counts as found (the acceptance cone and the dwell)
control_step           pressure_controller's step without ROS (the node and the offline replay)
controller_parameters  the controller's parameters in one table (declarations, scene, docs)
gaze_wire              the HoloLens gaze datagram (wire format v1)
display_wire           the display downlink to the headset (v1)
dummies                the speed task's distractors around the eye, uniform in solid angle, apart
clock_sync             the headset clock's offset and drift from the echo exchange
safe_input             reading outside files safely, with one-line errors naming the field
plot_style             how every figure shows the conditions, units and intervals; its text checks
"""
from .calibration import Calibration, CalibrationFileError, CalibrationProcedure, pressure_schedule
from .channels import ChannelMap, ChannelMapError
from .conditions import CONDITIONS, Condition, condition
from .feedback import (ADJUSTED, FILTERED, FIXED, FRONT, PAPER_GAIN, PAPER_P_MAX, REST, SIGN,
                       TARGET,
                       FeedbackLaw, GuidanceController, noise_rate_threshold)
from .geometry import (DIRECTIONS, GazeAngles, GeometryError, angles_between, split_directions,
                       ray_direction, ray_orientation, target_direction, unit_vector, unity_to_ros_point,
                       unity_to_ros_quaternion, wrap_deg)
from .power_law import CalibrationFitError, FitReport, PowerLaw, fit_power_law
from .speech import phrase

__all__ = [
    'ADJUSTED', 'FILTERED', 'FRONT', 'REST', 'SIGN', 'TARGET', 'noise_rate_threshold',
    'CONDITIONS', 'Calibration', 'CalibrationFileError', 'CalibrationFitError',
    'CalibrationProcedure', 'ChannelMap', 'ChannelMapError', 'Condition', 'DIRECTIONS', 'FIXED',
    'FeedbackLaw', 'FitReport', 'GazeAngles', 'GeometryError', 'GuidanceController', 'PAPER_GAIN',
    'PAPER_P_MAX', 'PowerLaw', 'angles_between', 'condition', 'fit_power_law', 'phrase',
    'pressure_schedule', 'ray_direction', 'ray_orientation', 'split_directions', 'target_direction', 'unit_vector',
    'unity_to_ros_point',
    'unity_to_ros_quaternion', 'wrap_deg',
]
