"""End-to-end runs through the stages, in this process."""
