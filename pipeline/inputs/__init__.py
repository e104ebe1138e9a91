"""Readers of user input files (scene JSON, demonstration JSON): parse, validate, and hand
back core objects, with one clear error naming the file and the culprit."""
