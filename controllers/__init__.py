"""Controllers for flexible-link FMUs (LQR, Kalman, PD) -- reserved for the controllers issue."""
