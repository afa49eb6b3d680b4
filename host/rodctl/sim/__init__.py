"""Simulator: C plant library (rod, motor, driver, encoder), closed-loop runner, scenarios, virtual device.

rodctl.sim.plant     Plant (C plant via ctypes), run_closed_loop, measure_realtime_factor, benchmark
rodctl.sim.accuracy  integrator accuracy against scipy Radau (python -m rodctl.sim.accuracy)
"""
