"""Simulator: C plant library (rod, motor, driver, encoder), closed-loop runner, scenarios, virtual device."""
