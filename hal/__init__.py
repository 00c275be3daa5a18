"""Hardware seams: servo bus, orientation tracker, camera and arm, each with a real driver,
an emulator beneath the real driver, and a behavioural fake."""
