__title__ = "attune-client"
__version__ = "0.1.0"
