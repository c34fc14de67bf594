"""The infrastructure shared by the commands of raytrace and positioning.

Both packages' command-line tools run on it, and both import it: it imports nothing of
:mod:`raytrace` or :mod:`positioning` (standard library and numpy only), so ``positioning`` still
never imports ``raytrace``. ``tools/check_layers.py`` enforces that.

* :mod:`hallray.errors` -- :class:`~hallray.errors.InputError`, the base of every error a user
  causes by bad input (``positioning.PositioningError`` derives from it);
* :mod:`hallray.harness` -- the command harness: one-line errors, exit codes, signals;
* :mod:`hallray.safe_output` -- the one safe output layer: files and directories appear whole or
  not at all, special files and inputs are refused, one writer at a time;
* :mod:`hallray.units` -- the scale rule (the largest hall) and the unit mistakes that break it.

The importing is cheap on purpose: every command imports the harness at its start. (The unified
``hallray`` console command will be a module of its own here; only it may import the two
packages.)
"""
