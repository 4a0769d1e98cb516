"""USD I/O: read UsdSkel shots, write fill layers, convert BVH, dailies (approve, publish).

Importing this package registers the TweenAPI schema plugin, which must happen before
the first stage is opened in the process.
"""

import usd_schemas

usd_schemas.register()
