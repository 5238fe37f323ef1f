"""The controller: the whole-body MPC, its diagnostics, the 500 Hz low level, the arm task."""
