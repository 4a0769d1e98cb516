"""USD round trip: read UsdSkel shots, map and retarget joints, write fill layers.

Importing this package registers the TweenAPI schema plugin, which must happen before
the first stage is opened in the process.
"""

import usd_schemas

usd_schemas.register()
