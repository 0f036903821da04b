"""The sensors the station carries or watches: the laser line scanner and the PhoXi structured-light scanner."""
