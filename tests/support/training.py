"""Training in tests ends by steps, never by the clock."""

# A seconds budget no test run reaches: `max_steps` ends training, so a loaded machine trains slower, never less
# (a budget the steps could outlast makes a test's result depend on the machine's load).
BY_STEPS_S = 1e6
