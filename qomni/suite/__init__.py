"""The blind suite of the sim-to-real gap diagnosis: cases drawn from a master seed (``cases``), run and
diagnosed against the twin or an ideal reference (``runner``), scored (``scoring``); and the campaign at
the ends of every effect's realistic range (``range_ends``)."""
