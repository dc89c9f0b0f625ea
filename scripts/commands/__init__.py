"""The CLI's commands, one module each (as evo has them): its parser (``add``), its
``--help`` texts (``HELP``) and the function it runs; the cores they call live beside them in
``swarmslam``."""
