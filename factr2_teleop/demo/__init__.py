"""`factr2 demo`: the main job on the built-in twin (SIMULATED): sim-piper + virtual operator + a table
contact/wipe task, bilateral force feedback, measured timing and feedback quality. See docs/demo.md."""
