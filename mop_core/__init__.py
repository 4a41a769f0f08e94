"""mop_core: the library behind the MOP pipeline (Multi-task Offline Policy distillation).

Stage scripts in ``stages/`` parse ``params.yaml`` into the typed configs defined here and call
one function each; nothing in this package reads ``params.yaml`` or invents output paths.
"""

__version__ = "0.1.0"
