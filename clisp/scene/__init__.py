"""What a raw's scene is: the statistics measured from the mosaic and the estimates made from
them (white balance passes 1 and 2, exposure, noise, the per-block analysis)."""
