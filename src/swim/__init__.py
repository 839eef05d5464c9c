"""SWIm: Simulated Weather Imagery, a fast visible-light 3D radiative transfer renderer for NWP output.

Physics after Albers et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020.
"""

import logging

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())
