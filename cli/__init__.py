"""The ``stiction`` command (Typer app). No numerics here: parse, call, render."""
