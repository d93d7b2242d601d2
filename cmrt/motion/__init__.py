"""What the character is asked to do: tasks (the record and the shipped task files), the reference motion,
sequences of motions, the CMRT curve, the robust ensemble and the library of shipped CMRTs."""
