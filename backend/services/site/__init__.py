"""The pool: the site's boundary, keep-outs and tags, versioned and published, and the geofence check of goals."""
