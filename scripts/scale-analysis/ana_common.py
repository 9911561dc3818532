import math
def load_cam(seq):
    c={}
    for l in open(f'{seq}/camera.yaml'):
        if l.startswith('Camera.') and ':' in l:
            k,v=l.split(':',1)
            try: c[k.strip()]=float(v)
            except ValueError: pass
    return c['Camera.fx'],c['Camera.fy'],c['Camera.cx'],c['Camera.cy'],c['Camera.bf']
def qrot(qx,qy,qz,qw):
    return [[1-2*(qy*qy+qz*qz),2*(qx*qy-qz*qw),2*(qx*qz+qy*qw)],
            [2*(qx*qy+qz*qw),1-2*(qx*qx+qz*qz),2*(qy*qz-qx*qw)],
            [2*(qx*qz-qy*qw),2*(qy*qz+qx*qw),1-2*(qx*qx+qy*qy)]]
def load_traj(p):
    d={}
    for l in open(p):
        if l.startswith('#') or not l.strip(): continue
        f=l.split(); t='%.6f'%float(f[0]); v=list(map(float,f[1:]))
        d[t]=(qrot(*v[3:7]),v[0:3])
    return d
def load_dump(out):
    pts=[]
    for l in open(f'{out}/mapdump.txt'):
        f=l.split()
        if f[0]=='P': pts.append(([float(x) for x in f[1:4]],[]))
        else: pts[-1][1].append(('%.6f'%float(f[1]),float(f[2]),float(f[3]),int(f[4]),float(f[5])))
    return pts
def mv(R,x): return [R[i][0]*x[0]+R[i][1]*x[1]+R[i][2]*x[2] for i in range(3)]
def mtv(R,x): return [R[0][i]*x[0]+R[1][i]*x[1]+R[2][i]*x[2] for i in range(3)]
def matmul(A,B): return [[sum(A[i][k]*B[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
def transpose(A): return [[A[j][i] for j in range(3)] for i in range(3)]
def dot(a,b): return sum(x*y for x,y in zip(a,b))
def norm(a): return math.sqrt(dot(a,a))
def expso3(w):
    th=norm(w)
    if th<1e-12: return [[1,-w[2],w[1]],[w[2],1,-w[0]],[-w[1],w[0],1]]
    k=[x/th for x in w]; K=[[0,-k[2],k[1]],[k[2],0,-k[0]],[-k[1],k[0],0]]
    K2=matmul(K,K); s=math.sin(th); c=1-math.cos(th)
    return [[(1 if i==j else 0)+s*K[i][j]+c*K2[i][j] for j in range(3)] for i in range(3)]
def solve(A,b):
    n=len(b); M=[A[i][:]+[b[i]] for i in range(n)]
    for c in range(n):
        p=max(range(c,n),key=lambda r:abs(M[r][c])); M[c],M[p]=M[p],M[c]
        for r in range(n):
            if r!=c:
                f=M[r][c]/M[c][c]
                for k in range(c,n+1): M[r][k]-=f*M[c][k]
    return [M[i][n]/M[i][i] for i in range(n)]
def pose_opt(P,Z,W,R,t,cam,iters=10,fixrot=False,huber_mono=math.sqrt(5.991),huber_st=math.sqrt(7.815)):
    FX,FY,CX,CY,BF=cam
    inl=0
    for it in range(iters):
        H=[[0.0]*6 for _ in range(6)]; g=[0.0]*6; inl=0
        for X,z,w in zip(P,Z,W):
            x=[a+b for a,b in zip(mv(R,X),t)]
            if x[2]<=1e-6: continue
            iz=1/x[2]; u=FX*x[0]*iz+CX; v=FY*x[1]*iz+CY
            r=[z[0]-u,z[1]-v]
            J=[[FX*iz,0,-FX*x[0]*iz*iz],[0,FY*iz,-FY*x[1]*iz*iz]]
            if z[2] is not None:
                r.append(z[2]-(u-BF*iz)); J.append([FX*iz,0,-(FX*x[0]-BF)*iz*iz]); th=huber_st
            else: th=huber_mono
            chi=w*sum(e*e for e in r)
            if it>=3 and chi>th*th*4: continue
            inl+=1
            e=math.sqrt(chi); k=1.0 if e<=th else th/e
            # d x / d delta (left perturbation): [-[x]x | I]
            for row,rr in zip(J,r):
                # Jpose = -row * [-[x]x | I] (residual = z - pi)
                jx=[row[1]*x[2]-row[2]*x[1], row[2]*x[0]-row[0]*x[2], row[0]*x[1]-row[1]*x[0]]
                Jp=[jx[0],jx[1],jx[2],-row[0],-row[1],-row[2]]
                for i in range(6):
                    g[i]+=w*k*Jp[i]*rr
                    for j in range(6): H[i][j]+=w*k*Jp[i]*Jp[j]
        if fixrot:
            for i in range(3):
                for j in range(6): H[i][j]=H[j][i]=0.0
                H[i][i]=1.0; g[i]=0.0
        d=solve(H,[-x for x in g])
        dR=expso3(d[:3]); R=matmul(dR,R); t=[a+b for a,b in zip(mv(dR,t),d[3:])]
    return R,t,inl
