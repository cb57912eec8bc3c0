"""What the software reads from images: particles, displacements, trace/retrace corrections.

- :mod:`.features`: particles found in images to a fraction of a pixel;
- :mod:`.registration`: displacement between two images by cross-correlation (scikit-image);
- :mod:`.mismatch`: the trace/retrace mismatch of an image, line by line;
- :mod:`.tip_estimate`: the tip's apex radius learnt from images of particles;
- :mod:`.loop_correction`: Section IV on a real trace/retrace image (the symmetric loop fitted
  on particle pairs, the image corrected).

May import the core, :mod:`piezocomp.io` and the loop fit of :mod:`piezocomp.identification`;
never the virtual AFM or experiments.
"""
