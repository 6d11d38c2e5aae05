"""Transport levels: local (Method I), radiosity (Method II), photon (Method III), behind one TransportLevel
interface."""
