"""Data sets built with the renderer and the victims: the "PASCAL3D+ renderings" set (:mod:`.rendering_set`) and
its contact sheet (:mod:`.rendering_set_sheet`). The packaged set lives in ``data/``."""
