"""The data types: demonstrations (:mod:`~sb3_cmzdril.data.demos`), the readers of other libraries'
episodes (:mod:`~sb3_cmzdril.data.readers`) and the observation and action spaces they are checked
against (:mod:`~sb3_cmzdril.data.spaces`). ``from sb3_cmzdril import Demonstrations`` as before."""
