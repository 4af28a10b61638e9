"""A robot's recorded sensor streams: the sensor-log format (:mod:`twin.logs.format`), the
twin's own runs written in it (:func:`twin.logs.format.write_log`), and estimators replayed on
a log, no physics involved (:mod:`twin.logs.replay`)."""
