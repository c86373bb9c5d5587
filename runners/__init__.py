"""How runs are executed: the ``nrtraffic`` command and its runners."""
