"""adversaries/rcg: Real-world Crash Grounding (thesis 7.4): crash-grounded selection of prior candidates, on top of
CAT (``cat-rcg``) and SEAL (``seal-rcg``)."""
