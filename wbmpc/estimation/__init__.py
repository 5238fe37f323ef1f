"""State estimation from the IMU and the joint encoders.

The names of the former module ``wbmpc.estimation`` are re-exported here from ``wbmpc.estimation.two_stage``.
"""

from wbmpc.estimation.two_stage import (
    EstimatorNoise,
    ImuNoise,
    ImuReading,
    JointReading,
    StateEstimator,
    contact_trust,
    synthesize_imu,
)

__all__ = [
    "EstimatorNoise",
    "ImuNoise",
    "ImuReading",
    "JointReading",
    "StateEstimator",
    "contact_trust",
    "synthesize_imu",
]
