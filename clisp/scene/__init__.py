"""What a raw's scene is: the estimates made from the mosaic before anything is decided (white
balance passes 1 and 2, exposure, noise, the per-block analysis), gathered by
:func:`clisp.scene.measure.measure_scene` into one :class:`clisp.scene.measure.Scene`."""
