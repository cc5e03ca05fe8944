"""The pipeline: decoded inputs held on a fixed-step schedule, the one step of every cylinder
(supervision, estimator, isolation, detector, headroom) and the output table it writes. Live and replay
drive the same compiled step (step.py); engine.py builds its records from a config and a model."""
