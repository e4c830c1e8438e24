"""The Python client's tests: the client against a real daemon, and the example notebook run as
Jupyter runs it (nbclient and ipykernel are in the current and board envs' requirements; the armhf
subset does not take these modules).
"""
