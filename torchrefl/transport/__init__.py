"""Transport levels: local (direct light with shadows); later radiosity and photon."""
