"""CiA 402 drives on CANopen (python-canopen over python-can): see .drive."""
