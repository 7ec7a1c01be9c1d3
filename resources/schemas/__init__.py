"""JSON Schema (draft 2020-12) files of ringlight's JSON documents: the impulse dataset's
``dataset.json``, the simulator's scene and the stack export's ``stack.json``
(``docs/format`` specifies them; ringlight's own checks go further, see there)."""
