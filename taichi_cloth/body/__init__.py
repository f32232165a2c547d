"""The body the cloth is worn on, posed on the host: the capsule skeleton and its dance
(``dancer.py`` with the choreography in ``hula.py``), and static props to drape over
(``props.py``)."""
