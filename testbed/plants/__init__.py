"""Plain (non-MuJoCo) plants: the papers' example systems under the testbed's conventions."""
