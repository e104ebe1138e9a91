"""The application layer: typed settings (Hydra schemas over the algorithms' parameter
classes), factories that build objects from them, and the run context the stages share."""
