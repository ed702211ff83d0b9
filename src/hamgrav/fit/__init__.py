"""Fitting: the solver base and outcomes, Levenberg-Marquardt (+ Kaula), Adam, the Kaula
scan, continual fits, D-optimal orbit selection, and the estimator (the one fit path)."""
