"""The design folder: its checks and atomic write (:mod:`.folder`), one writer per file group
(:mod:`.writers`), the pictures, the report (:mod:`.report`), the assembly guide
(:mod:`.assembly_guide`) and ``drawstring simulate`` on a written folder
(:mod:`.folder_simulation`).
"""
