"""The Robotino of Section II: body and drive dynamics (eqs. 1-10), their integration, encoders, speed loops."""
