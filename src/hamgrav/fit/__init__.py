"""Fitting: the solver base and outcomes, Levenberg-Marquardt (+ Kaula), Adam, the Kaula
scan, model selection by cross-validation, continual fits, D-optimal orbit selection, and the
estimator (the one fit path)."""
