"""The run-time machinery around the search core: compiled programs and their chunked, timed
runs (`programs`, `anytime`), sharding over devices, the persistent compilation cache, signals,
progress lines and atomic files."""
