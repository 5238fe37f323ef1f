"""The controller: the whole-body MPC, its prechecks, the 500 Hz low level, the arm task."""
