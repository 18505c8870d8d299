"""``seal fit probes`` and ``seal eval steering``: latent probes, steering / control vectors and their evaluation
(papers 000 and 002; `seal.models.steering`)."""
