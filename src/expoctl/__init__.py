"""expoctl: learned camera gain and exposure control for visual odometry."""
__version__ = "0.1.0"
