"""The design folder: its atomic write (:mod:`.folder`), one writer per file group
(:mod:`.writers`), pictures, the report and the assembly guide.
"""
