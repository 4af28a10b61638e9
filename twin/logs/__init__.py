"""A robot's recorded sensor streams: the sensor-log format (:mod:`twin.logs.format`), the
twin's own runs written in it (:func:`twin.logs.format.write_log`), and estimators replayed on
a log, no physics involved (:mod:`twin.logs.replay`). A log is input from outside: what it may
ask for is bounded (:mod:`twin.logs.bounds`), its streams are read row by row into arrays
(:mod:`twin.logs.streams`), and a replay keeps the estimators' diagnostics as arrays
(:mod:`twin.logs.diagnostics`)."""
