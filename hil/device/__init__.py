"""The device side of the vehicle's CANopen network: the CiA 301 node machinery, the CiA 402 drives,
the CiA 406 encoders, the lock-step server around a plant (its contract: :mod:`.plant`) and the fault
injection of the emulated bus."""
