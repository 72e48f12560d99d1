"""The sub-commands of the instruments: demo, simulate, bench, stress."""
