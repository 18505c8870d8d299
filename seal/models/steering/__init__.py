"""Latent steering and control vectors on the trajectory prior (papers ``000`` and ``002``; ARCHITECTURE.md).

* `latents`: the prior's hidden states at each encoder site (input embedding, after each transformer layer, the
  normed output) for one target per scene, and decoding with an offset added to the target's state at a site.
* `labels`: behavioural labels of futures (logged or predicted): the kinematic activity risk of paper 000, a
  scene-aware proximity risk, and paper 002's quantised motion classes.
* `linear`: ridge probes, softmax probes, PCA-whitened mean-difference vectors, PCA control vectors.
* `sae`: sparse autoencoders on latents and the SAE-refined control vectors.
* `bundle`: the fitted steering vectors of a prior as one file (``seal fit probes``), and `SteeringVector`.

Everything here needs torch; import the submodules directly.
"""
